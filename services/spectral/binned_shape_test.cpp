#include "services/spectral/binned_shape.h"

#include <cmath>
#include <random>
#include <vector>

#include "gtest/gtest.h"
#include "services/spectral/named_spectra.h"
#include "services/spectral/pixel_tables.h"
#include "services/spectral/testing/chi_square.h"
#include "services/spectral/wavelength_grid.h"

namespace prism::spectral {
namespace {

constexpr double kThreshold = 1e-4;  // reject when p < 1e-4
constexpr int kSamples = 200000;

// The job default of a scene lit by CIE F11 alone: emitter term × flat sensor, mixed with 5 %
// uniform over F11's support, on 1 nm cells (what RenderScene builds).
WavelengthDistribution f11_default() {
  const SpectrumLibrary lib = *SpectrumLibrary::load_builtin();
  const std::vector<Spectrum> f11 = {*lib.find_spectrum("stdillum-F11")};
  const WavelengthDistribution emitters = *WavelengthDistribution::emitters(f11, 470);
  return *emitters.mix_defensive(0.05, emitters);
}

// A default with mass on 40 cells only (no defensive term): most bins have no default mass.
WavelengthDistribution narrow_band_default() {
  std::vector<double> w(470, 0.0);
  for (int c = 200; c < 240; ++c) w[c] = 1.0 + (c % 3);
  return *WavelengthDistribution::from_table(w);
}

std::vector<double> random_weights(int n, std::mt19937_64& rng) {
  std::uniform_real_distribution<double> u(0.0, 1.0);
  std::vector<double> w(static_cast<std::size_t>(n));
  for (double& x : w) x = u(rng) < 0.2 ? 0.0 : u(rng) * u(rng);
  w[static_cast<std::size_t>(n / 2)] = 1.0;  // never all zero
  return w;
}

// A random pixel table of `bins` bins as a worker receives it: random_weights, quantised.
std::vector<std::uint16_t> random_cdf(int bins, std::mt19937_64& rng) {
  return WavelengthDistribution::from_table(random_weights(bins, rng))->quantise();
}

// The composite's mass over [lo, hi) computed from the default's own cdf and the table's
// integer masses, independently of BinnedShape: Σ_b m_b · P_d([lo, hi) ∩ b) / P_d(b), or the
// uniform fraction of the bin where P_d(b) = 0.
double oracle_mass(const WavelengthDistribution& d, std::span<const std::uint16_t> q, int bins,
                   double lo, double hi) {
  double mass = 0.0;
  for (int b = 0; b < bins; ++b) {
    const double b0 = uniform_cell_lower(b, bins), b1 = uniform_cell_lower(b + 1, bins);
    const double a = std::max(lo, b0), z = std::min(hi, b1);
    if (z <= a) continue;
    const double m = (q[b + 1] - q[b]) / 65535.0;
    const double whole = d.cdf(float(b1)) - d.cdf(float(b0));
    mass +=
        whole > 1e-12 ? m * (d.cdf(float(z)) - d.cdf(float(a))) / whole : m * (z - a) / (b1 - b0);
  }
  return mass;
}

// With `composite` (assigned to shape and table), its samples instead of the two-step sampler's.
void expect_samples_match(const BinnedShape& shape, const QuantisedWavelengthCdf& table,
                          const WavelengthDistribution& d, int histogram_cells, std::uint64_t seed,
                          const CompositeCdf* composite = nullptr) {
  std::mt19937_64 rng(seed);
  std::uniform_real_distribution<double> u(0.0, 1.0);
  std::vector<double> observed(static_cast<std::size_t>(histogram_cells), 0.0),
      expected(static_cast<std::size_t>(histogram_cells), 0.0);
  for (int i = 0; i < kSamples; ++i) {
    const double x = u(rng);
    const WavelengthSample s = composite != nullptr ? composite->sample(x) : shape.sample(table, x);
    ASSERT_GE(s.lambda, kLambdaMin);
    ASSERT_LE(s.lambda, kLambdaMax);
    ASSERT_GT(s.pdf, 0.0f) << "sampled a zero-density wavelength " << s.lambda;
    ASSERT_EQ(s.pdf, shape.pdf(table, s.lambda)) << "at " << s.lambda;
    observed[static_cast<std::size_t>(uniform_cell_of(s.lambda, histogram_cells))] += 1.0;
  }
  for (int h = 0; h < histogram_cells; ++h) {
    expected[static_cast<std::size_t>(h)] =
        kSamples * oracle_mass(d, table.values(), shape.bins(),
                               uniform_cell_lower(h, histogram_cells),
                               uniform_cell_lower(h + 1, histogram_cells));
  }
  const testing::ChiSquareResult r = testing::chi_square(observed, expected);
  EXPECT_GT(r.p_value, kThreshold) << r.describe();
}

// Random bin masses with F11's shape inside each bin: a chi-square test at 1 nm (F11's lines
// must keep their shape inside 7.3 nm bins) and at 5 nm, and pdf == the returned density.
TEST(BinnedShapeTest, SamplesFollowTheTableWithTheDefaultShapeInsideBins) {
  const WavelengthDistribution d = f11_default();
  std::mt19937_64 rng(3);
  for (int bins : {64, 17, 4}) {
    const BinnedShape shape = *BinnedShape::create(d, bins);
    const std::vector<std::uint16_t> cdf = random_cdf(bins, rng);
    const QuantisedWavelengthCdf table = *QuantisedWavelengthCdf::create(cdf);
    SCOPED_TRACE(bins);
    expect_samples_match(shape, table, d, 470, 11 + bins);
    expect_samples_match(shape, table, d, 94, 12 + bins);
  }
}

// With the default's own bin masses the composite is the default, up to quantising D_b: the
// ratio of densities is m_b / D_b, within one part in the bin's integer units.
TEST(BinnedShapeTest, TheDefaultsOwnBinMassesGiveTheDefault) {
  const WavelengthDistribution d = f11_default();
  const BinnedShape shape = *BinnedShape::create(d, 64);
  double total = 0.0;
  for (double m : shape.bin_masses()) total += m;
  EXPECT_NEAR(total, 1.0, 1e-12);
  const std::vector<std::uint16_t> cdf =
      WavelengthDistribution::from_table(shape.bin_masses())->quantise();
  const QuantisedWavelengthCdf table = *QuantisedWavelengthCdf::create(cdf);
  for (float lambda = 360.05f; lambda < 830.0f; lambda += 0.1f) {
    const int b = uniform_cell_of(lambda, 64);
    const double units = cdf[b + 1] - cdf[b];
    const double want = d.pdf(lambda), got = shape.pdf(table, lambda);
    if (want == 0.0) {
      EXPECT_EQ(got, 0.0) << lambda;
      continue;
    }
    ASSERT_NEAR(got / want, 1.0, 1.0 / units + 1e-5) << lambda << " nm, bin " << b;
  }
}

// The density integrates to 1, and the cdf is its integral.
TEST(BinnedShapeTest, CdfIsTheIntegralOfThePdf) {
  const WavelengthDistribution d = f11_default();
  std::mt19937_64 rng(5);
  const BinnedShape shape = *BinnedShape::create(d, 64);
  const std::vector<std::uint16_t> cdf =
      WavelengthDistribution::from_table(random_weights(64, rng))->quantise();
  const QuantisedWavelengthCdf table = *QuantisedWavelengthCdf::create(cdf);
  // Midpoint rule on a 1/32 nm grid: every 1 nm cell edge and every bin edge (multiples of
  // 470/64 = 235/32 nm) is a grid line, so the density is constant on each step and the sum is
  // exact up to rounding.
  const double step = 1.0 / 32;
  double acc = 0.0;
  for (int i = 0; i < 470 * 32; ++i) {
    const double lo = 360.0 + i * step;
    acc += double(shape.pdf(table, float(lo + 0.5 * step))) * step;
    if (i % 97 == 0) {
      ASSERT_NEAR(shape.cdf(table, float(lo + step)), acc, 1e-6) << lo;
    }
  }
  EXPECT_NEAR(acc, 1.0, 1e-6);
  EXPECT_EQ(shape.cdf(table, 359.0f), 0.0);
  EXPECT_EQ(shape.cdf(table, 830.0f), 1.0);
}

// A bin with table mass and no default mass is sampled uniformly inside: a narrow-band default
// (no defensive term) and a flat table.
TEST(BinnedShapeTest, BinsWithoutDefaultMassAreUniformInside) {
  const WavelengthDistribution d = narrow_band_default();
  const BinnedShape shape = *BinnedShape::create(d, 32);
  int empty = 0;
  for (int b = 0; b < 32; ++b) empty += shape.bin_mass(b) == 0.0 ? 1 : 0;
  EXPECT_GT(empty, 20);
  const std::vector<std::uint16_t> cdf = WavelengthDistribution::flat(32)->quantise();
  const QuantisedWavelengthCdf table = *QuantisedWavelengthCdf::create(cdf);
  expect_samples_match(shape, table, d, 94, 21);
  // Bin 0 holds its quantised 1/32 of the mass, spread evenly over its 14.6875 nm.
  const double units = cdf[1] - cdf[0];
  EXPECT_NEAR(shape.pdf(table, 365.0f), units / 65535.0 / (470.0 / 32), 1e-9);
  EXPECT_EQ(shape.pdf(table, 361.0f), shape.pdf(table, 374.0f));
}

// CMIS lanes are the rotated single samples.
TEST(BinnedShapeTest, LanesAreRotatedSamples) {
  const WavelengthDistribution d = f11_default();
  std::mt19937_64 rng(8);
  const BinnedShape shape = *BinnedShape::create(d, 64);
  const std::vector<std::uint16_t> cdf =
      WavelengthDistribution::from_table(random_weights(64, rng))->quantise();
  const QuantisedWavelengthCdf table = *QuantisedWavelengthCdf::create(cdf);
  std::uniform_real_distribution<double> u(0.0, 1.0);
  for (int i = 0; i < 500; ++i) {
    const double v = u(rng);
    const SampledWavelengths lanes = shape.sample_lanes(table, v, 4);
    for (int s = 0; s < 4; ++s) {
      double r = v + s / 4.0;
      if (r >= 1.0) r -= 1.0;
      const WavelengthSample one = shape.sample(table, r);
      ASSERT_EQ(lanes.lambda(s), one.lambda);
      ASSERT_EQ(lanes.pdf(s), one.pdf);
    }
  }
}

// The guided searches (the pixel's bin guide, then the default's cell guide) find what the full
// searches find: the same λ and density for random u, for u on every guide interval's edge and
// every bin's edge and a float step either side, with line spectra, bins without default mass,
// table bins without mass, and from 1 to 300 bins.
TEST(BinnedShapeTest, GuidedSamplesAreTheFullSearchsSamples) {
  const std::vector<WavelengthDistribution> defaults = {f11_default(), narrow_band_default()};
  std::mt19937_64 rng(17);
  std::uniform_real_distribution<double> uniform(0.0, 1.0);
  for (const WavelengthDistribution& d : defaults) {
    for (int bins : {1, 7, 32, 64, 300}) {
      const BinnedShape shape = *BinnedShape::create(d, bins);
      const std::vector<std::uint16_t> cdf = random_cdf(bins, rng);
      const QuantisedWavelengthCdf table = *QuantisedWavelengthCdf::create(cdf);
      std::vector<std::uint16_t> guide(std::size_t(BinnedShape::guide_entries(bins)));
      BinnedShape::build_guide(table, guide);
      std::vector<double> us;
      for (int i = 0; i < 2000; ++i) us.push_back(uniform(rng));
      const int intervals = int(guide.size()) - 1;
      for (int j = 0; j <= intervals; ++j) us.push_back(double(j) * (65536 / intervals) / 65535.0);
      for (std::uint16_t q : cdf) us.push_back(q / 65535.0);
      const std::size_t edges = us.size();
      for (std::size_t i = 0; i < edges; ++i) {
        us.push_back(std::nextafter(us[i], 0.0));
        us.push_back(std::nextafter(us[i], 1.0));
      }
      for (double u : us) {
        const WavelengthSample full = shape.sample(table, u);
        const WavelengthSample guided = shape.sample(table, u, guide.data());
        ASSERT_EQ(guided.lambda, full.lambda) << bins << " bins, u = " << u;
        ASSERT_EQ(guided.pdf, full.pdf) << bins << " bins, u = " << u;
        ASSERT_GT(full.pdf, 0.0f) << bins << " bins, u = " << u;
        ASSERT_EQ(full.pdf, shape.pdf(table, full.lambda)) << bins << " bins, u = " << u;
      }
    }
  }
}

// The composite CDF samples the same density as the two-step sampler: a chi-square test at 1 nm
// and 5 nm, its density equal to pdf() for every sample, and for random u the λ of the same
// inverse CDF to rounding (at a u exactly on the edge of a bin the two may take either side).
TEST(BinnedShapeTest, CompositeSamplesAreTheTwoStepSamplesToRounding) {
  const std::vector<WavelengthDistribution> defaults = {f11_default(), narrow_band_default()};
  std::mt19937_64 rng(23);
  std::uniform_real_distribution<double> uniform(0.0, 1.0);
  CompositeCdf composite;  // reassigned throughout, as the tile renderer does
  // A random table, and one whose bins but one hold a single unit each: their pieces are far
  // thinner than the composite's guide intervals, so those intervals span many pieces (the
  // composite's longer search) and the rest of the guide one bin's pieces.
  auto spiky_cdf = [](int bins) {
    std::vector<std::uint16_t> cdf(std::size_t(bins) + 1, 0);
    const int heavy = bins / 3;
    for (int b = 0; b < bins; ++b) cdf[b + 1] = cdf[b] + (b == heavy ? 65535 - (bins - 1) : 1);
    return cdf;
  };
  for (const WavelengthDistribution& d : defaults) {
    for (int bins : {1, 7, 32, 64, 256, -32, -256}) {
      const bool spiky = bins < 0;
      bins = std::abs(bins);
      const BinnedShape shape = *BinnedShape::create(d, bins);
      const std::vector<std::uint16_t> cdf = spiky ? spiky_cdf(bins) : random_cdf(bins, rng);
      const QuantisedWavelengthCdf table = *QuantisedWavelengthCdf::create(cdf);
      composite.assign(shape, table);
      for (int i = 0; i < 5000; ++i) {
        const double u = uniform(rng);
        const WavelengthSample a = composite.sample(u), b = shape.sample(table, u);
        ASSERT_NEAR(a.lambda, b.lambda, 1e-3) << bins << " bins, u = " << u;
        ASSERT_EQ(a.pdf, shape.pdf(table, a.lambda)) << bins << " bins, u = " << u;
      }
      std::vector<double> edges = {0.0, 1e-300, std::nextafter(1.0, 0.0), 1.0, 2.0, -1.0};
      for (std::uint16_t q : cdf) {
        edges.push_back(q / 65535.0);
        edges.push_back(std::nextafter(q / 65535.0, 0.0));
        edges.push_back(std::nextafter(q / 65535.0, 1.0));
      }
      for (double u : edges) {
        const WavelengthSample a = composite.sample(u);
        ASSERT_GT(a.pdf, 0.0f) << bins << " bins, u = " << u;
        ASSERT_EQ(a.pdf, shape.pdf(table, a.lambda)) << bins << " bins, u = " << u;
      }
    }
  }
  const WavelengthDistribution d = f11_default();
  const BinnedShape shape = *BinnedShape::create(d, 64);
  const std::vector<std::uint16_t> cdf =
      WavelengthDistribution::from_table(random_weights(64, rng))->quantise();
  const QuantisedWavelengthCdf table = *QuantisedWavelengthCdf::create(cdf);
  composite.assign(shape, table);
  expect_samples_match(shape, table, d, 470, 31, &composite);
  expect_samples_match(shape, table, d, 94, 32, &composite);
  // Lanes are the rotated single samples, also through a view.
  const WavelengthPdfView view(composite);
  for (int i = 0; i < 500; ++i) {
    const double v = uniform(rng);
    const SampledWavelengths lanes = view.sample_lanes(v, 4);
    for (int s = 0; s < 4; ++s) {
      double r = v + s / 4.0;
      if (r >= 1.0) r -= 1.0;
      const WavelengthSample one = composite.sample(r);
      ASSERT_EQ(lanes.lambda(s), one.lambda);
      ASSERT_EQ(lanes.pdf(s), one.pdf);
      ASSERT_EQ(view.pdf(one.lambda), one.pdf);
    }
  }
}

// Edges of u and of Λ stay inside the support with a positive density.
TEST(BinnedShapeTest, ExtremesOfUStayInsideTheSupport) {
  const WavelengthDistribution d = f11_default();
  const BinnedShape shape = *BinnedShape::create(d, 64);
  std::mt19937_64 rng(13);
  const std::vector<std::uint16_t> cdf =
      WavelengthDistribution::from_table(random_weights(64, rng))->quantise();
  const QuantisedWavelengthCdf table = *QuantisedWavelengthCdf::create(cdf);
  for (double u : {0.0, 1e-300, 1e-9, 0.5, 1.0 - 1e-12, std::nextafter(1.0, 0.0), 1.0, 2.0, -1.0}) {
    const WavelengthSample s = shape.sample(table, u);
    EXPECT_GT(s.pdf, 0.0f) << u;
    EXPECT_EQ(s.pdf, shape.pdf(table, s.lambda)) << u;
  }
  EXPECT_FALSE(BinnedShape::create(d, 0).ok());
  EXPECT_FALSE(BinnedShape::create(d, WavelengthDistribution::kMaxCells + 1).ok());
}

}  // namespace
}  // namespace prism::spectral
