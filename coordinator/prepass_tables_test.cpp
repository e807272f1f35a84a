// The prepass's tables (prepass_tables.cpp) and the moments they are learned from: the
// variance model, the choice per pixel, the fallbacks, encoding and upsampling.
#include <tbb/task_arena.h>

#include <algorithm>
#include <cmath>
#include <cstring>
#include <limits>
#include <random>
#include <string>
#include <vector>

#include "coordinator/prepass.h"
#include "gtest/gtest.h"
#include "services/base/testing/status_says.h"
#include "services/spectral/binned_shape.h"
#include "services/spectral/pixel_tables.h"
#include "services/spectral/testing/chi_square.h"
#include "services/spectral/wavelength_grid.h"

namespace prism::coordinator {
namespace {

using image::SpectralImage;
using spectral::WavelengthDistribution;

std::vector<double> partial_default(int bins = 32) {
  std::vector<double> w(static_cast<size_t>(bins), 0.0);
  double total = 0.0;
  for (int b = 4; b < bins - 4; ++b) {
    w[b] = 1.0 + 0.5 * std::sin(0.7 * b) + (b == 13 ? 30.0 : 0.0);
    total += w[b];
  }
  for (double& x : w) x /= total;
  return w;
}

int quantised_units(std::span<const std::uint16_t> cdf, int b) {
  return cdf[b + 1] - cdf[b];
}

// Guides that keep the rows apart (depths 1 apart, σ_r = 0.015) and join the pixels of a row.
GuideImage row_guides(int width, int height) {
  GuideImage g = *GuideImage::create(width, height);
  for (int y = 0; y < height; ++y)
    for (int x = 0; x < width; ++x) g.set(x, y, {float(y), 0, 1, 0, 0.5f});
  return g;
}

// A moment image (2·bins channels: K_b, then U_b) with every pixel of row y holding rows[y].
struct Moments {
  std::vector<double> k, u;
};
SpectralImage moments_image(int width, const std::vector<Moments>& rows) {
  const int bins = int(rows[0].k.size());
  SpectralImage img = *SpectralImage::create(width, int(rows.size()), 2 * bins);
  for (std::size_t y = 0; y < rows.size(); ++y)
    for (int x = 0; x < width; ++x)
      for (int b = 0; b < bins; ++b) {
        img.value(x, int(y), b) = float(rows[y].k[b]);
        img.value(x, int(y), bins + b) = float(rows[y].u[b]);
      }
  return img;
}

// The oracle of build_tables for a pixel whose neighbours all share its moments (then the
// filtered moments, the ones without the pixel and its own agree), written out from prepass.h.
struct Choice {
  int alpha = 0;
  TableShape shape = TableShape::kSecondMoment;
  std::vector<double> masses;  // the table, unquantised
  double v0 = 0, v = 0;
};
Choice choose(const Moments& m, const std::vector<double>& d, const std::vector<double>& sensor,
              const VarianceModel& model, const job::PrepassParameters& params) {
  const std::size_t n = d.size();
  std::vector<double> k(n), u(n);
  for (std::size_t b = 0; b < n; ++b) {
    const double s2 = sensor.empty() ? 1.0 : sensor[b] * sensor[b];
    k[b] = d[b] > 0 ? s2 * float(m.k[b]) : 0.0;
    u[b] = d[b] > 0 ? s2 * float(m.u[b]) : 0.0;
  }
  auto variance = [&](const std::vector<double>& masses) {
    double v = 0;
    for (std::size_t b = 0; b < n; ++b) {
      if (d[b] > 0) v += model.bin_variance(k[b], u[b], masses[b]);
    }
    return v;
  };
  Choice best;
  best.masses = d;
  best.v0 = best.v = variance(d);
  const double r = double(model.prepass_lanes) / model.final_lanes;
  for (int s = 0; s < kTableShapes; ++s) {
    std::vector<double> shape(n);
    double sum = 0;
    for (std::size_t b = 0; b < n; ++b) {
      const double g = s == 0 ? r * k[b] : r * k[b] - u[b] / model.final_lanes;
      shape[b] = g > 0 ? std::sqrt(g) : 0.0;
      sum += shape[b];
    }
    if (!(sum > 0)) continue;
    for (int a = 1; a < kAlphaChoices; ++a) {
      const double alpha = alpha_choice(a, params.epsilon);
      std::vector<double> masses(n);
      for (std::size_t b = 0; b < n; ++b) masses[b] = alpha * shape[b] / sum + (1 - alpha) * d[b];
      const double v = variance(masses);
      if (v < best.v) {
        best = {a, TableShape(s), masses, best.v0, v};
      }
    }
  }
  if (!(best.v0 > 0) || !(best.v <= (1 - params.fallback) * best.v0)) {
    best.alpha = 0;
    best.v = best.v0;
  }
  return best;
}

// CMIS lanes drawn from bin masses w (uniform inside each bin) over a spectrum f with per-lane
// noise: per bin the sums and squared sums of N samples' values X_b = Σ_lanes f·(1 + ξ)/(C·p),
// as the tile renderer accumulates them, in a one-pixel tile.
image::TileResult simulate(const std::vector<double>& w, const std::vector<double>& f, int lanes,
                           std::uint64_t samples, std::uint64_t seed) {
  const int bins = int(w.size());
  const WavelengthDistribution q = *WavelengthDistribution::from_table(w);
  image::TileResult tile = *image::TileResult::create({0, 0, 1, 1}, {0, samples}, bins, {});
  std::mt19937_64 rng(seed);
  std::uniform_real_distribution<double> u(0.0, 1.0);
  std::vector<double> x(bins);
  for (std::uint64_t i = 0; i < samples; ++i) {
    std::fill(x.begin(), x.end(), 0.0);
    const spectral::SampledWavelengths l = q.sample_lanes(u(rng), lanes);
    for (int s = 0; s < lanes; ++s) {
      const int b = q.cell_of(l.lambda(s));
      x[b] += f[b] * (1.0 + (u(rng) - 0.5) * 1.6) / (lanes * l.pdf(s) * (470.0 / bins));
    }
    for (int b = 0; b < bins; ++b) {
      tile.mutable_sums()[b] += x[b];
      tile.mutable_sum_squares()[b] += x[b] * x[b];
    }
  }
  tile.mutable_counts()[0] = samples;
  return tile;
}

// The moments K (taken out of the lanes' pairs) and U measured with one set of masses predict the
// per-sample variance under another, with any number of lanes per bin: against the variance
// measured there, within five standard errors of that measurement.
TEST(VarianceModelTest, MomentsPredictTheVarianceOfCmisLanesAtOtherMasses) {
  constexpr int kBins = 8;
  const std::vector<double> f = {0.2, 1.0, 3.0, 0.5, 2.0, 0.1, 1.5, 0.7};
  // Masses from under 1/C in every bin to two and more lanes in one.
  const std::vector<double> measured_with = {0.08, 0.1, 0.3, 0.05, 0.2, 0.07, 0.12, 0.08};
  const std::vector<std::vector<double>> judged = {
      {0.125, 0.125, 0.125, 0.125, 0.125, 0.125, 0.125, 0.125},
      {0.02, 0.1, 0.55, 0.03, 0.15, 0.02, 0.1, 0.03},
      {0.3, 0.05, 0.05, 0.2, 0.1, 0.1, 0.1, 0.1}};
  for (int lanes : {1, 4}) {
    const VarianceModel model{lanes, lanes, false};
    auto moments = MomentImage::create(1, 1, kBins);
    ASSERT_TRUE(moments.ok());
    ASSERT_TRUE(moments
                    ->add_tile(simulate(measured_with, f, lanes, 400000, 7 + lanes), nullptr,
                               measured_with, lanes)
                    .ok());
    const float* m = moments->moments().pixel(0, 0).data();
    for (std::size_t j = 0; j < judged.size(); ++j) {
      double predicted = 0;
      for (int b = 0; b < kBins; ++b)
        predicted += model.bin_variance(m[b], m[kBins + b], judged[j][b]);
      const image::TileResult t = simulate(judged[j], f, lanes, 400000, 100 + j + lanes);
      // Per bin the sample variance and the standard error of the total (the bins' X are
      // correlated, so the error of the sum is taken from the per-sample sums' spread below).
      double variance = 0;
      for (int b = 0; b < kBins; ++b) {
        const double mean = t.sum(0, 0, b) / 400000.0;
        variance += t.sum_squares(0, 0, b) / 400000.0 - mean * mean;
      }
      // The sample variance of a sum of heavy-ish terms: its relative standard error is at most
      // sqrt((κ − 1)/N); with the bounded values here κ < 30, so 5 SE < 5·sqrt(29/4e5) = 4.3 %.
      EXPECT_NEAR(predicted / variance, 1.0, 0.043) << lanes << " lanes, masses " << j;
    }
  }
  EXPECT_EQ(pairs_of_lanes(4, 0.2), 0.0);
  EXPECT_EQ(pairs_of_lanes(4, 0.5), 2.0);    // always 2 lanes: 2·1
  EXPECT_EQ(pairs_of_lanes(4, 0.375), 1.0);  // 1 or 2 lanes, half each: (0 + 2)/2
}

// Pixels that agree learn their shared shape: the candidate of least predicted variance, by the
// oracle, for both models and with a sensor weight; its table is α·shape + (1 − α)·D quantised,
// and every bin with default mass keeps (1 − α)·D_b.
TEST(PrepassTablesTest, AgreeingPixelsTakeTheCandidateOfLeastPredictedVariance) {
  constexpr int kBins = 32, kW = 5;
  const std::vector<double> d = partial_default(kBins);
  std::vector<double> sensor(kBins);
  for (int b = 0; b < kBins; ++b) sensor[b] = 0.5 + std::abs(std::sin(0.2 * b)) * 1.2;
  std::mt19937_64 rng(7);
  std::uniform_real_distribution<double> u(0.0, 1.0);
  std::vector<Moments> rows;
  for (int y = 0; y < 12; ++y) {
    // From K ∝ D² (the default is the optimum) to a few strong bins, U from 0 to large.
    Moments m{std::vector<double>(kBins, 0.0), std::vector<double>(kBins, 0.0)};
    const double peak = y / 11.0;
    for (int b = 0; b < kBins; ++b) {
      if (d[b] == 0) continue;
      m.k[b] = d[b] * d[b] * (1 - peak) + (u(rng) < 0.2 ? peak * 0.01 * u(rng) : 0.0);
      m.u[b] =
          m.k[b] * 4.0 * u(rng) * (y % 3) / 2.0;  // 0 to 4K: a lane's value from noisy to exact
    }
    rows.push_back(m);
  }
  const SpectralImage img = moments_image(kW, rows);
  const GuideImage guides = row_guides(kW, int(rows.size()));
  job::PrepassParameters params;
  int learned = 0, shapes[2] = {0, 0};
  for (bool stratified : {false, true}) {
    for (const std::vector<double>& weights : {std::vector<double>{}, sensor}) {
      const VarianceModel model{4, 4, stratified};
      auto tables = build_tables(img, guides, params, d, weights, model);
      ASSERT_TRUE(tables.ok()) << tables.status();
      for (int y = 0; y < int(rows.size()); ++y) {
        const Choice want = choose(rows[y], d, weights, model, params);
        for (int x = 0; x < kW; ++x) {
          SCOPED_TRACE(::testing::Message() << "row " << y << " x " << x << " stratified "
                                            << stratified << " sensor " << !weights.empty());
          ASSERT_EQ(tables->alpha_index(x, y), want.alpha);
          EXPECT_NEAR(tables->predicted_default_variance(x, y), want.v0, 1e-4 * std::abs(want.v0));
          if (want.alpha == 0) {
            EXPECT_EQ(tables->source(x, y), PixelSource::kMatchesDefault);
            for (std::uint16_t v : tables->cdf(x, y)) ASSERT_EQ(v, 0);
            continue;
          }
          ++learned;
          ++shapes[int(want.shape)];
          EXPECT_EQ(tables->source(x, y), PixelSource::kLearned);
          EXPECT_EQ(tables->shape(x, y), want.shape);
          EXPECT_NEAR(tables->predicted_variance(x, y), want.v, 1e-4 * std::abs(want.v0));
          const std::vector<std::uint16_t> oracle =
              WavelengthDistribution::from_table(want.masses)->quantise();
          const double alpha = alpha_choice(want.alpha, params.epsilon);
          for (int b = 0; b < kBins; ++b) {
            EXPECT_NEAR(quantised_units(tables->cdf(x, y), b), oracle[b + 1] - oracle[b], 1) << b;
            if (d[b] > 0) {
              EXPECT_GE(quantised_units(tables->cdf(x, y), b),
                        std::max(1.0, std::floor(65535.0 * (1 - alpha) * d[b]) - 1))
                  << b;
            } else {
              EXPECT_EQ(quantised_units(tables->cdf(x, y), b), 0) << b;
            }
          }
        }
      }
      EXPECT_EQ(tables->source(0, 0), PixelSource::kMatchesDefault);  // K ∝ D²
      std::int64_t total = 0;
      for (std::int64_t c : tables->alpha_histogram()) total += c;
      EXPECT_EQ(total, kW * std::int64_t(rows.size()));
      const auto by_shape = tables->shape_histogram();
      EXPECT_EQ(by_shape[0] + by_shape[1], tables->count(PixelSource::kLearned));
    }
  }
  // The rows cover the cases: defaults, several mixture weights, both shapes.
  EXPECT_GT(learned, 0);
  EXPECT_GT(shapes[0], 0);
  EXPECT_GT(shapes[1], 0);
}

// A pixel's own samples do not shape the table they judge: where each pixel's moments are noise
// around one shared truth, tables learned from the pixel itself would always look better than the
// default; judged by the neighbours' moments they do not, and the pixels stay on the default.
TEST(PrepassTablesTest, NoiseAroundTheDefaultsOptimumIsNotLearned) {
  constexpr int kBins = 16, kW = 24, kH = 24;
  const std::vector<double> d(kBins, 1.0 / kBins);
  std::mt19937_64 rng(3);
  std::gamma_distribution<double> noise(2.0, 0.5);  // mean 1, heavy-ish
  SpectralImage img = *SpectralImage::create(kW, kH, 2 * kBins);
  for (int y = 0; y < kH; ++y)
    for (int x = 0; x < kW; ++x)
      for (int b = 0; b < kBins; ++b) img.value(x, y, b) = float(d[b] * d[b] * noise(rng));
  GuideImage guides = *GuideImage::create(kW, kH);
  for (int y = 0; y < kH; ++y)
    for (int x = 0; x < kW; ++x) guides.set(x, y, {0.5f, 0, 1, 0, 0.5f});
  auto tables = build_tables(img, guides, {}, d, {}, VarianceModel{4, 4, false});
  ASSERT_TRUE(tables.ok()) << tables.status();
  EXPECT_LT(tables->count(PixelSource::kLearned), kW * kH / 20);
  EXPECT_LT(tables->predicted_gain(), 0.05);
}

// Pixels with nothing to learn from, or with non-finite moments, keep the default; a small gain
// stays on the default unless `fallback` is 0; pixels without a table stay so in later passes;
// reset_to_default puts every pixel back.
TEST(PrepassTablesTest, DefaultWhereNothingIsLearnedOrTheGainIsSmall) {
  constexpr int kBins = 16, kW = 4;
  const std::vector<double> d(kBins, 1.0 / kBins);
  const VarianceModel model{4, 4, false};
  std::vector<Moments> rows(
      5, Moments{std::vector<double>(kBins, 0.0), std::vector<double>(kBins, 0.0)});
  // 0: all zero. 1: a NaN. 2: one bin holds everything. 3: a slight tilt (a few per cent).
  // 4: negative moments only.
  rows[1].k[3] = std::numeric_limits<double>::quiet_NaN();
  rows[2].k[5] = 1.0;
  for (int b = 0; b < kBins; ++b) rows[3].k[b] = (1.0 + 0.12 * (b % 2)) / (kBins * kBins);
  for (int b = 0; b < kBins; ++b) rows[4].k[b] = -1.0;
  const SpectralImage img = moments_image(kW, rows);
  const GuideImage guides = row_guides(kW, 5);
  job::PrepassParameters params;
  auto tables = build_tables(img, guides, params, d, {}, model);
  ASSERT_TRUE(tables.ok()) << tables.status();
  EXPECT_EQ(tables->source(1, 0), PixelSource::kNoEstimate);
  EXPECT_EQ(tables->source(1, 1), PixelSource::kNoEstimate);
  EXPECT_EQ(tables->source(1, 2), PixelSource::kLearned);
  EXPECT_EQ(tables->alpha_index(1, 2), kAlphaChoices - 1);
  EXPECT_EQ(tables->source(1, 3), PixelSource::kMatchesDefault);
  EXPECT_EQ(tables->source(1, 4), PixelSource::kNoEstimate);
  const Choice slight = choose(rows[3], d, {}, model, [] {
    job::PrepassParameters p;
    p.fallback = 0.0;
    return p;
  }());
  const double gain = 1.0 - slight.v / slight.v0;
  EXPECT_GT(gain, 0.0);
  EXPECT_LT(gain, params.fallback);
  params.fallback = 0.0;
  auto loose = build_tables(img, guides, params, d, {}, model);
  EXPECT_EQ(loose->source(1, 3), PixelSource::kLearned);
  EXPECT_DOUBLE_EQ(tables->fallback_fraction(), 4.0 / 5.0);

  // Later passes keep whatever had no table, whatever their moments now say.
  std::vector<Moments> later_rows(
      5, Moments{std::vector<double>(kBins, 0.0), std::vector<double>(kBins, 0.0)});
  for (Moments& m : later_rows) m.k[7] = 1.0;
  auto later = build_tables(moments_image(kW, later_rows), guides, job::PrepassParameters{}, d, {},
                            model, &*tables);
  ASSERT_TRUE(later.ok());
  EXPECT_EQ(later->source(0, 0), PixelSource::kNoEstimate);
  EXPECT_EQ(later->source(0, 3), PixelSource::kMatchesDefault);
  EXPECT_EQ(later->source(0, 2), PixelSource::kLearned);
  EXPECT_GT(quantised_units(later->cdf(0, 2), 7), 60000);

  later->reset_to_default();
  EXPECT_EQ(later->count(PixelSource::kLearned), 0);
  EXPECT_EQ(later->predicted_gain(), 0.0);
  for (std::uint16_t v : later->cdf(0, 2)) ASSERT_EQ(v, 0);
}

TEST(PrepassTablesTest, RefusesMismatchedInputs) {
  SpectralImage img = *SpectralImage::create(2, 2, 32);
  const GuideImage guides = row_guides(2, 2);
  const std::vector<double> d16(16, 1.0 / 16), d8(8, 1.0 / 8);
  const VarianceModel model;
  EXPECT_TRUE(build_tables(img, guides, {}, d16, {}, model).ok());
  absl::Status s = build_tables(img, guides, {}, d8, {}, model).status();
  EXPECT_EQ(s.code(), absl::StatusCode::kInvalidArgument);
  EXPECT_TRUE(status_says(s, "8 default masses")) << s;
  EXPECT_FALSE(build_tables(img, guides, {}, d16, d8, model).ok());
  EXPECT_FALSE(build_tables(img, guides, {}, std::vector<double>(16, 0.0), {}, model).ok());
  std::vector<double> negative = d16;
  negative[3] = -0.1;
  EXPECT_FALSE(build_tables(img, guides, {}, negative, {}, model).ok());
  job::PrepassParameters bad;
  bad.epsilon = 2.0;
  EXPECT_TRUE(status_says(build_tables(img, guides, bad, d16, {}, model).status(), "epsilon"));
  EXPECT_FALSE(build_tables(*SpectralImage::create(2, 2, 31), guides, {}, d16, {}, model).ok());
  EXPECT_FALSE(build_tables(img, row_guides(3, 2), {}, d16, {}, model).ok());
  SpectralImage other = *SpectralImage::create(3, 2, 32);
  auto prev = build_tables(other, row_guides(3, 2), {}, d16, {}, model);
  ASSERT_TRUE(prev.ok());
  EXPECT_FALSE(build_tables(img, guides, {}, d16, {}, model, &*prev).ok());
}

// A prepass tile's moments: U the unbiased μ², K = w·M − pairs·U/(C²·w) with w the bin mass the
// pixel was sampled with; passes average by sample count.
TEST(MomentImageTest, MomentsAreSampleMassTimesMeanSquareAveragedOverPasses) {
  constexpr int kBins = 4, kLanes = 4;
  const std::vector<double> d = {0.1, 0.2, 0.3, 0.4};
  auto m = MomentImage::create(3, 2, kBins);
  ASSERT_TRUE(m.ok()) << m.status();
  image::TileBuffers buffers;
  buffers.guides = true;
  auto tile = image::TileResult::create({0, 0, 3, 2}, {0, 4}, kBins, buffers);
  ASSERT_TRUE(tile.ok());
  // Pixel (0,0): 4 samples; pixel (1,0): none (skipped); the rest 4 samples of zeros.
  const double sums[kBins] = {1.0, 2.0, 0.0, 4.0}, squares[kBins] = {0.5, 3.0, 0.0, 8.0};
  for (int b = 0; b < kBins; ++b) {
    tile->mutable_sums()[b] = sums[b];
    tile->mutable_sum_squares()[b] = squares[b];
  }
  tile->mutable_counts()[0] = 4;
  for (int p = 2; p < 6; ++p) tile->mutable_counts()[p] = 4;
  ASSERT_TRUE(m->add_tile(*tile, nullptr, d, kLanes).ok());
  std::vector<double> k_first(kBins), u_first(kBins);
  for (int b = 0; b < kBins; ++b) {
    const double mean = sums[b] / 4, second = squares[b] / 4;
    u_first[b] = mean * mean - (second - mean * mean) / 3;
    k_first[b] = d[b] * second - pairs_of_lanes(kLanes, d[b]) * u_first[b] / (16 * d[b]);
    EXPECT_FLOAT_EQ(m->moments().value(0, 0, b), float(k_first[b])) << b;
    EXPECT_FLOAT_EQ(m->moments().value(0, 0, kBins + b), float(u_first[b])) << b;
  }
  EXPECT_GT(pairs_of_lanes(kLanes, d[3]), 0.0);  // bin 3 (mass 0.4) takes 1 or 2 lanes
  EXPECT_EQ(m->samples(1, 0), 0.0);
  for (int c = 0; c < 2 * kBins; ++c) EXPECT_EQ(m->moments().value(1, 0, c), 0.0f);

  // A second pass of 12 samples at a one-pixel image, sampled with a table: w its masses.
  job::PrepassParameters p;
  p.fallback = 0.0;
  Moments strong{{1.0, 4.0, 1.0, 1.0}, {0, 0, 0, 0}};
  // Three agreeing pixels (a lone pixel has no neighbours to learn from).
  auto tables = build_tables(moments_image(3, {strong}), row_guides(3, 1), p, d, {},
                             VarianceModel{kLanes, kLanes, false});
  ASSERT_TRUE(tables.ok());
  auto small = MomentImage::create(3, 1, kBins);
  auto t1 = image::TileResult::create({0, 0, 1, 1}, {0, 4}, kBins, buffers);
  for (int b = 0; b < kBins; ++b) {
    t1->mutable_sums()[b] = sums[b];
    t1->mutable_sum_squares()[b] = squares[b];
  }
  t1->mutable_counts()[0] = 4;
  ASSERT_TRUE(small->add_tile(*t1, nullptr, d, kLanes).ok());
  if (tables->source(0, 0) == PixelSource::kLearned) {
    auto t2 = image::TileResult::create({0, 0, 1, 1}, {4, 16}, kBins, buffers);
    const double squares2[kBins] = {2.4, 1.2, 0.6, 3.6};
    for (int b = 0; b < kBins; ++b) t2->mutable_sum_squares()[b] = squares2[b];
    t2->mutable_counts()[0] = 12;
    ASSERT_TRUE(small->add_tile(*t2, &*tables, d, kLanes).ok());
    const std::span<const std::uint16_t> cdf = tables->cdf(0, 0);
    for (int b = 0; b < kBins; ++b) {
      const double w = (cdf[b + 1] - cdf[b]) / 65535.0;
      const double u2 = -(squares2[b] / 12) / 11;  // mean 0: μ̂² − (M − μ̂²)/(n − 1)
      const double k2 = w * squares2[b] / 12 - pairs_of_lanes(kLanes, w) * u2 / (16 * w);
      EXPECT_NEAR(small->moments().value(0, 0, b), 0.25 * k_first[b] + 0.75 * k2,
                  1e-5 * std::max(1.0, std::abs(k2)))
          << b;
      EXPECT_NEAR(small->moments().value(0, 0, kBins + b), 0.25 * u_first[b] + 0.75 * u2, 1e-5)
          << b;
    }
    EXPECT_EQ(small->samples(0, 0), 16.0);
  } else {
    ADD_FAILURE() << "the strong one-pixel moments should have given a table";
  }

  auto outside = image::TileResult::create({2, 1, 4, 2}, {0, 1}, kBins, buffers);
  EXPECT_FALSE(m->add_tile(*outside, nullptr, d, kLanes).ok());
  EXPECT_FALSE(m->add_tile(*tile, nullptr, std::vector<double>(3, 0.3), kLanes).ok());
  EXPECT_FALSE(MomentImage::create(0, 1, 4).ok());
}

// Pipeline tables through the wire: encode a tile, decode it as a worker would, and check every
// pixel's table bytes and that CMIS lanes, drawn with the default's shape inside each bin, put
// each bin's quantised mass in it.
TEST(PrepassTablesTest, TilesRoundTripAndSampleTheirQuantisedBinMasses) {
  constexpr int kW = 7, kH = 5, kBins = 64;
  // A default distribution on 1 nm cells with lines (every 9th nm ten times denser).
  std::vector<double> fine(470);
  for (int c = 0; c < 470; ++c) fine[c] = c % 9 == 0 ? 10.0 : 1.0;
  const WavelengthDistribution job_default = *WavelengthDistribution::from_table(fine);
  const spectral::BinnedShape shape = *spectral::BinnedShape::create(job_default, kBins);
  const std::vector<double>& d = shape.bin_masses();
  // Each row's pixels share a spectrum, so every pixel's neighbours agree with it: row 0 peaked
  // (a narrow line), rows 1, 3, 4 random, row 2 the default's own optimum (stays default).
  std::mt19937_64 rng(8);
  std::uniform_real_distribution<double> u(0.0, 1.0);
  std::vector<Moments> rows;
  for (int y = 0; y < kH; ++y) {
    Moments m{std::vector<double>(kBins), std::vector<double>(kBins, 0.0)};
    for (int b = 0; b < kBins; ++b) m.k[b] = u(rng) * u(rng) * u(rng) * d[b];
    if (y == 0) {
      for (int b = 0; b < kBins; ++b) m.k[b] = b == 10 ? 1e4 : 1e-9;
    }
    if (y == 2) {
      for (int b = 0; b < kBins; ++b) m.k[b] = d[b] * d[b];
    }
    rows.push_back(m);
  }
  auto tables = build_tables(moments_image(kW, rows), row_guides(kW, kH), {}, d, {},
                             VarianceModel{4, 4, false});
  ASSERT_TRUE(tables.ok());
  ASSERT_EQ(tables->source(2, 2), PixelSource::kMatchesDefault);
  const image::TileRect rect{1, 1, 5, 4};
  auto bytes = tables->encode_tile(rect);
  ASSERT_TRUE(bytes.ok());
  ASSERT_EQ(bytes->size(), spectral::pixel_table_bytes(4, 3, kBins));
  auto decoded = spectral::PixelTables::decode(4, 3, kBins, *bytes);
  ASSERT_TRUE(decoded.ok()) << decoded.status();
  EXPECT_EQ(decoded->default_pixels(), 4);   // row 2 of the tile
  EXPECT_TRUE(decoded->uses_default(1, 1));  // image pixel (2, 2)

  constexpr int kSamples = 60000;
  const double threshold = spectral::testing::sidak_threshold(1e-4, 5 * 4);
  int tested = 0;
  for (int ty = 0; ty < 3; ++ty) {
    for (int tx = 0; tx < 4; ++tx) {
      const spectral::QuantisedWavelengthCdf* q = decoded->table(tx, ty);
      if (q == nullptr) continue;
      const std::span<const std::uint16_t> cdf = tables->cdf(rect.x0 + tx, rect.y0 + ty);
      ASSERT_TRUE(std::equal(cdf.begin(), cdf.end(), q->values().begin()));
      if (tested == 5) continue;
      ++tested;
      const spectral::WavelengthPdfView view = decoded->view(tx, ty, job_default, shape);
      for (int lane = 0; lane < 4; ++lane) {
        std::vector<double> observed(kBins, 0.0), expected(kBins, 0.0);
        for (int i = 0; i < kSamples; ++i) {
          const spectral::SampledWavelengths s = view.sample_lanes(u(rng), 4);
          ASSERT_EQ(s.pdf(lane), view.pdf(s.lambda(lane)));
          observed[spectral::uniform_cell_of(s.lambda(lane), kBins)] += 1.0;
        }
        for (int b = 0; b < kBins; ++b)
          expected[b] = double(kSamples) * (cdf[b + 1] - cdf[b]) / 65535.0;
        const auto r = spectral::testing::chi_square(observed, expected);
        EXPECT_GT(r.p_value, threshold)
            << tx << "," << ty << " lane " << lane << ": " << r.describe();
      }
    }
  }
  EXPECT_EQ(tested, 5);
  EXPECT_FALSE(tables->encode_tile({5, 3, 8, 5}).ok());
  EXPECT_FALSE(tables->encode_tile({2, 2, 2, 4}).ok());
}

TEST(PrepassTablesTest, UpsamplingTakesThePixelHoldingEachCentre) {
  constexpr int kBins = 8;
  std::vector<Moments> rows;
  for (int y = 0; y < 3; ++y) {
    Moments m{std::vector<double>(kBins, 0.0), std::vector<double>(kBins, 0.0)};
    m.k[(2 * y) % kBins] = 1.0;
    rows.push_back(m);
  }
  const std::vector<double> d(kBins, 1.0 / kBins);
  auto low = build_tables(moments_image(2, rows), row_guides(2, 3), {}, d, {}, VarianceModel{});
  ASSERT_TRUE(low.ok());
  ASSERT_EQ(low->count(PixelSource::kLearned), 6);
  auto high = upsample_tables(*low, 5, 7);
  ASSERT_TRUE(high.ok());
  for (int y = 0; y < 7; ++y) {
    for (int x = 0; x < 5; ++x) {
      const int sx = int((x + 0.5) * 2 / 5), sy = int((y + 0.5) * 3 / 7);
      const auto a = high->cdf(x, y), b = low->cdf(sx, sy);
      ASSERT_TRUE(std::equal(a.begin(), a.end(), b.begin())) << x << "," << y;
      ASSERT_EQ(high->source(x, y), low->source(sx, sy));
      ASSERT_EQ(high->alpha_index(x, y), low->alpha_index(sx, sy));
      ASSERT_EQ(high->shape(x, y), low->shape(sx, sy));
    }
  }
  EXPECT_FALSE(upsample_tables(*low, 0, 4).ok());
}

}  // namespace
}  // namespace prism::coordinator
