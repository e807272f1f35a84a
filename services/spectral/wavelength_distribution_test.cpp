#include "services/spectral/wavelength_distribution.h"

#include <algorithm>
#include <cmath>
#include <functional>
#include <random>
#include <vector>

#include "gtest/gtest.h"
#include "services/spectral/named_spectra.h"
#include "services/spectral/testing/chi_square.h"
#include "services/spectral/wavelength_grid.h"

namespace prism::spectral {
namespace {

constexpr double kThreshold = 1e-4;  // reject when p < 1e-4
constexpr int kSamples = 200000;
constexpr int kHistogramCells = 94;  // 5 nm, deliberately not aligned with most pdf grids

// Draws kSamples with `draw`, checks each returned pdf equals `pdf` at the returned λ exactly,
// and runs a chi-square test of the histogram against expected counts from `cdf`.
void expect_sampler_matches(const std::function<WavelengthSample(double)>& draw,
                            const std::function<float(float)>& pdf,
                            const std::function<double(float)>& cdf, uint64_t seed,
                            const char* what) {
  std::mt19937_64 rng(seed);
  std::uniform_real_distribution<double> u(0.0, 1.0);
  std::vector<double> observed(kHistogramCells, 0.0), expected(kHistogramCells, 0.0);
  const WavelengthGrid hist = *WavelengthGrid::create(kHistogramCells);
  for (int i = 0; i < kSamples; ++i) {
    const WavelengthSample s = draw(u(rng));
    ASSERT_GE(s.lambda, kLambdaMin) << what;
    ASSERT_LE(s.lambda, kLambdaMax) << what;
    ASSERT_GT(s.pdf, 0.0f) << what << " sampled a zero-density wavelength " << s.lambda;
    ASSERT_EQ(s.pdf, pdf(s.lambda)) << what << " at " << s.lambda;
    observed[hist.bin_of(s.lambda)] += 1.0;
  }
  for (int b = 0; b < kHistogramCells; ++b) {
    const double hi = b + 1 == kHistogramCells ? 1.0 : cdf(hist.upper(b));
    expected[b] = kSamples * (hi - cdf(hist.lower(b)));
  }
  const testing::ChiSquareResult r = testing::chi_square(observed, expected);
  EXPECT_GT(r.p_value, kThreshold) << what << ": " << r.describe();
}

// The cdf must be the integral of the pdf.
void expect_cdf_integrates_pdf(const WavelengthDistribution& d) {
  double acc = 0.0;
  for (int i = 0; i < d.cells(); ++i) {
    acc += static_cast<double>(d.cell_pdf(i)) * d.cell_width();
    const float upper = static_cast<float>(360.0 + (i + 1) * d.cell_width());
    ASSERT_NEAR(d.cdf(upper), acc, 1e-5) << i;
  }
  EXPECT_NEAR(acc, 1.0, 1e-5);
}

void expect_distribution_ok(const WavelengthDistribution& d, uint64_t seed, const char* what) {
  expect_cdf_integrates_pdf(d);
  expect_sampler_matches([&](double u) { return d.sample(u); }, [&](float l) { return d.pdf(l); },
                         [&](float l) { return d.cdf(l); }, seed, what);
}

std::vector<Spectrum> f11_and_a() {
  const SpectrumLibrary lib = *SpectrumLibrary::load_builtin();
  return {*lib.find_spectrum("stdillum-F11"), *lib.find_spectrum("stdillum-A")};
}

TEST(WavelengthDistributionTest, FlatSamplerMatchesPdf) {
  const WavelengthDistribution d = *WavelengthDistribution::flat();
  EXPECT_FLOAT_EQ(d.pdf(500.0f), 1.0f / 470.0f);
  EXPECT_EQ(d.pdf(359.0f), 0.0f);
  EXPECT_EQ(d.cdf(300.0f), 0.0);
  EXPECT_EQ(d.cdf(900.0f), 1.0);
  EXPECT_NEAR(d.cdf(595.0f), 0.5, 1e-9);
  expect_distribution_ok(d, 1, "flat");
}

TEST(WavelengthDistributionTest, VisibleSamplerMatchesPdfAndShape) {
  const WavelengthDistribution d = *WavelengthDistribution::visible();
  // Normalised continuous density: ∫ sech² = (tanh(a(830−538)) − tanh(a(360−538)))/a.
  const double a = 0.0072;
  const double norm = (std::tanh(a * (830 - 538)) - std::tanh(a * (360 - 538))) / a;
  for (float l : {380.5f, 538.5f, 700.5f, 829.5f}) {
    const double c = 1.0 / std::pow(std::cosh(a * (l - 538.0)), 2) / norm;
    EXPECT_NEAR(d.pdf(l), c, 1e-4 * c) << l;
  }
  expect_distribution_ok(d, 2, "visible");
  expect_distribution_ok(*WavelengthDistribution::visible(64), 3, "visible 64");
}

TEST(WavelengthDistributionTest, EmitterSamplerMatchesPdf) {
  const std::vector<Spectrum> emitters = f11_and_a();
  const WavelengthDistribution d = *WavelengthDistribution::emitters(emitters);
  expect_distribution_ok(d, 4, "emitters F11 + A");
  // Each emitter contributes half of the mass: check against the normalised sum directly.
  const double f11 = integrate(emitters[0], 360, 830), a = integrate(emitters[1], 360, 830);
  const double expected =
      0.5 * (integrate(emitters[0], 545, 546) / f11 + integrate(emitters[1], 545, 546) / a);
  EXPECT_NEAR(d.cdf(546.0f) - d.cdf(545.0f), expected, 1e-6);
  // F11 emits nothing below 380 nm, A does: the mixture is positive there; the product with a
  // sensor keeps zero where either is zero.
  const std::vector<Spectrum> f11_only = {emitters[0]};
  const WavelengthDistribution f = *WavelengthDistribution::emitters(f11_only);
  EXPECT_EQ(f.pdf(370.0f), 0.0f);
  EXPECT_GT(d.pdf(370.0f), 0.0f);
}

TEST(WavelengthDistributionTest, RandomTableWithZeroCellsNeverSamplesThem) {
  std::mt19937_64 rng(99);
  std::uniform_real_distribution<double> u(0.0, 1.0);
  std::vector<double> w(200);
  for (size_t i = 0; i < w.size(); ++i) w[i] = (i % 7 == 3 || i < 5 || i > 190) ? 0.0 : u(rng);
  const WavelengthDistribution d = *WavelengthDistribution::from_table(w);
  for (size_t i = 0; i < w.size(); ++i) {
    if (w[i] == 0.0) {
      EXPECT_EQ(d.cell_pdf(static_cast<int>(i)), 0.0f);
    }
  }
  // Samples exactly on zero-mass boundaries: u = cdf at a zero cell must land in the next
  // positive cell.
  for (int i = 0; i < 200; ++i) {
    const WavelengthSample s = d.sample(d.cdf(static_cast<float>(360.0 + i * 470.0 / 200)));
    EXPECT_GT(s.pdf, 0.0f);
    EXPECT_NE(w[d.cell_of(s.lambda)], 0.0);
  }
  EXPECT_GT(d.sample(0.0).pdf, 0.0f);
  EXPECT_GT(d.sample(std::nextafter(1.0, 0.0)).pdf, 0.0f);
  EXPECT_GT(d.sample(1.0).pdf, 0.0f);
  expect_distribution_ok(d, 5, "random table");
}

// sample() starts its search from a guide; the cell it returns must be the one a search of the
// whole CDF returns, the last c with cdf(c) <= u, for any u: random ones, the guide's own
// boundaries j/2^m and their neighbours, the cells' CDF values (zero-mass runs included), on
// tables of 1 to 16384 cells, spiky and flat.
TEST(WavelengthDistributionTest, TheGuidedSearchFindsTheCellAndWavelengthOfTheWholeSearch) {
  std::mt19937_64 rng(1234);
  std::uniform_real_distribution<double> uniform(0.0, 1.0);
  const SpectrumLibrary lib = *SpectrumLibrary::load_builtin();
  std::vector<WavelengthDistribution> tables = {
      *WavelengthDistribution::emitters(f11_and_a()),
      *WavelengthDistribution::emitters(std::vector<Spectrum>{*lib.find_spectrum("lamp-lps")}),
      *WavelengthDistribution::visible(), *WavelengthDistribution::flat(1),
      *WavelengthDistribution::flat(WavelengthDistribution::kMaxCells)};
  for (int cells : {2, 3, 200, 4096}) {
    std::vector<double> w(static_cast<std::size_t>(cells));
    for (double& x : w) x = uniform(rng) < 0.3 ? 0.0 : std::pow(uniform(rng), 8.0);
    w[static_cast<std::size_t>(cells) / 2] = 1.0;
    tables.push_back(*WavelengthDistribution::from_table(w));
  }
  for (const WavelengthDistribution& d : tables) {
    const int n = d.cells();
    auto whole = [&](double u) {
      u = std::clamp(u, 0.0, std::nextafter(1.0, 0.0));
      int c = 0;
      for (int i = 0; i < n; ++i) {
        if (d.cell_cdf(i) <= u) c = i;
      }
      return c;
    };
    std::vector<double> us;
    for (int i = 0; i < 2000; ++i) us.push_back(uniform(rng));
    for (int j = 0; j <= 4 * n && j <= 70000; ++j) {
      const double g = double(j) / (4 * n);
      for (double u : {g, std::nextafter(g, 0.0), std::nextafter(g, 1.0)}) us.push_back(u);
    }
    for (int i = 0; i <= n && i <= 20000; ++i) us.push_back(d.cell_cdf(i));
    // λ of the cell's linear inverse, moved a float at a time into the cell (what sample() did
    // before it clamped to each cell's precomputed first and last float).
    auto settled = [&](double u, int c) {
      u = std::clamp(u, 0.0, std::nextafter(1.0, 0.0));
      const double c0 = d.cell_cdf(c), c1 = d.cell_cdf(c + 1);
      const double t = std::clamp((u - c0) / (c1 - c0), 0.0, 1.0);
      const double lower = double{kLambdaMin} + double{kLambdaRange} * c / n;
      float lambda = static_cast<float>(lower + t * (double{kLambdaRange} / n));
      lambda = std::clamp(lambda, kLambdaMin, kLambdaMax);
      while (d.cell_of(lambda) > c) lambda = std::nextafter(lambda, 0.0f);
      while (d.cell_of(lambda) < c) lambda = std::nextafter(lambda, kLambdaMax);
      return lambda;
    };
    for (double u : us) {
      const int c = whole(u);
      const float lambda = d.sample(u).lambda;
      ASSERT_EQ(d.cell_of(lambda), c) << n << " cells, u " << u;
      ASSERT_EQ(lambda, settled(u, c)) << n << " cells, u " << u;
    }
  }
}

TEST(WavelengthDistributionTest, RefusesBadTables) {
  const std::vector<double> zeros(10, 0.0);
  EXPECT_EQ(WavelengthDistribution::from_table(zeros).status().code(),
            absl::StatusCode::kInvalidArgument);
  const std::vector<double> negative = {1.0, -1.0};
  EXPECT_FALSE(WavelengthDistribution::from_table(negative).ok());
  const std::vector<double> nan = {1.0, NAN};
  EXPECT_FALSE(WavelengthDistribution::from_table(nan).ok());
  EXPECT_FALSE(WavelengthDistribution::from_table(std::vector<double>{}).ok());
  EXPECT_FALSE(WavelengthDistribution::flat(0).ok());
  EXPECT_FALSE(WavelengthDistribution::emitters(std::vector<Spectrum>{}).ok());
  const std::vector<Spectrum> dark = {ConstantSpectrum{0.0f}};
  EXPECT_FALSE(WavelengthDistribution::emitters(dark).ok());
  const std::vector<Spectrum> negative_light = {ConstantSpectrum{-1.0f}};
  EXPECT_FALSE(WavelengthDistribution::emitters(negative_light).ok());
  const std::vector<double> left = {1, 0}, right = {0, 1};
  EXPECT_FALSE(WavelengthDistribution::product(*WavelengthDistribution::from_table(left),
                                               *WavelengthDistribution::from_table(right))
                   .ok());
  EXPECT_FALSE(WavelengthDistribution::product(*WavelengthDistribution::flat(10),
                                               *WavelengthDistribution::flat(11))
                   .ok());
}

TEST(WavelengthDistributionTest, ProductAndDefensiveMixture) {
  const std::vector<Spectrum> emitters = f11_and_a();
  const std::vector<Spectrum> f11_only = {emitters[0]};
  const WavelengthDistribution e = *WavelengthDistribution::emitters(f11_only);
  const WavelengthDistribution s = *WavelengthDistribution::visible();
  const WavelengthDistribution p = *WavelengthDistribution::product(s, e);
  for (int i = 0; i < p.cells(); i += 17) {
    if (e.cell_mass(i) == 0.0) {
      EXPECT_EQ(p.cell_mass(i), 0.0);
    }
  }
  const double eps = WavelengthDistribution::kDefaultDefensiveEpsilon;
  const WavelengthDistribution m = *p.mix_defensive(eps, e);
  int support = 0;
  for (int i = 0; i < e.cells(); ++i) support += e.cell_mass(i) > 0.0 ? 1 : 0;
  for (int i = 0; i < m.cells(); ++i) {
    const double want = (1.0 - eps) * p.cell_mass(i) + (e.cell_mass(i) > 0.0 ? eps / support : 0.0);
    ASSERT_NEAR(m.cell_mass(i), want, 1e-12) << i;
    if (e.cell_mass(i) > 0.0) {
      ASSERT_GE(m.cell_mass(i), eps / support * (1 - 1e-9));
    }
  }
  expect_distribution_ok(m, 6, "visible × F11, defensive");
  EXPECT_FALSE(p.mix_defensive(1.5, e).ok());
  EXPECT_FALSE(p.mix_defensive(0.05, *WavelengthDistribution::flat(64)).ok());
}

TEST(WavelengthDistributionTest, QuantisedTableSamplesItsOwnPdf) {
  const std::vector<Spectrum> emitters = f11_and_a();
  const WavelengthDistribution d = *WavelengthDistribution::emitters(emitters, 64);
  const std::vector<uint16_t> bits = d.quantise();
  ASSERT_EQ(bits.size(), 65u);
  const QuantisedWavelengthCdf q = *QuantisedWavelengthCdf::create(bits);
  for (int i = 0; i < d.cells(); ++i) {
    EXPECT_EQ(d.cell_mass(i) > 0.0, q.cell_pdf(i) > 0.0f) << i;
    EXPECT_NEAR(q.cell_pdf(i) * d.cell_width(), d.cell_mass(i), 1.0 / 65535) << i;
  }
  expect_sampler_matches([&](double u) { return q.sample(u); }, [&](float l) { return q.pdf(l); },
                         [&](float l) { return q.cdf(l); }, 7, "quantised");
  // A table with a tiny positive cell keeps it positive after quantisation.
  std::vector<double> w(100, 1.0);
  w[10] = 1e-12;
  w[11] = 0.0;
  const std::vector<uint16_t> tiny = WavelengthDistribution::from_table(w)->quantise();
  const QuantisedWavelengthCdf tq = *QuantisedWavelengthCdf::create(tiny);
  EXPECT_GT(tq.cell_pdf(10), 0.0f);
  EXPECT_EQ(tq.cell_pdf(11), 0.0f);
  std::vector<uint16_t> bad = bits;
  bad.back() = 100;
  EXPECT_FALSE(QuantisedWavelengthCdf::create(bad).ok());
  bad = bits;
  std::swap(bad[10], bad[20]);
  EXPECT_FALSE(QuantisedWavelengthCdf::create(bad).ok());
}

TEST(WavelengthDistributionTest, LaneRotationMarginalsMatchPdf) {
  const std::vector<Spectrum> emitters = f11_and_a();
  const WavelengthDistribution d = *WavelengthDistribution::emitters(emitters);
  const std::vector<uint16_t> bits = d.quantise();
  const QuantisedWavelengthCdf q = *QuantisedWavelengthCdf::create(bits);
  for (int lanes : {1, 4, 8}) {
    for (int lane = 0; lane < lanes; ++lane) {
      const std::string what = "lane " + std::to_string(lane) + " of " + std::to_string(lanes);
      expect_sampler_matches(
          [&](double u) {
            const SampledWavelengths w = d.sample_lanes(u, lanes);
            EXPECT_EQ(w.count(), lanes);
            return WavelengthSample{w.lambda(lane), w.pdf(lane)};
          },
          [&](float l) { return d.pdf(l); }, [&](float l) { return d.cdf(l); },
          100 + lanes * 10 + lane, what.c_str());
    }
  }
  expect_sampler_matches(
      [&](double u) {
        const SampledWavelengths w = q.sample_lanes(u, 4);
        return WavelengthSample{w.lambda(3), w.pdf(3)};
      },
      [&](float l) { return q.pdf(l); }, [&](float l) { return q.cdf(l); }, 200,
      "quantised lane 3 of 4");
  // The rotation itself: lane s is the inverse cdf at (u + s/C) mod 1.
  const SampledWavelengths w = d.sample_lanes(0.9, 4);
  EXPECT_EQ(w.lambda(0), d.sample(0.9).lambda);
  EXPECT_EQ(w.lambda(1), d.sample(0.15).lambda);
  EXPECT_EQ(w.lambda(3), d.sample(0.65).lambda);
  EXPECT_NEAR(d.cdf(w.lambda(2)), 0.4, 1e-6);
}

}  // namespace
}  // namespace prism::spectral
