#include "services/spectral/pixel_tables.h"

#include <algorithm>
#include <cmath>
#include <numeric>
#include <random>
#include <string>
#include <vector>

#include "gtest/gtest.h"
#include "services/spectral/testing/chi_square.h"
#include "services/spectral/wavelength_distribution.h"
#include "services/spectral/wavelength_grid.h"

namespace prism::spectral {
namespace {

// Random weights with zeros, tiny and huge entries: what filtered prepass estimates look like.
std::vector<double> random_weights(int n, std::mt19937_64& rng) {
  std::uniform_real_distribution<double> u(0.0, 1.0);
  std::vector<double> w(static_cast<size_t>(n));
  for (double& x : w) {
    const double r = u(rng);
    x = r < 0.2 ? 0.0 : r < 0.3 ? 1e-12 * u(rng) : r < 0.35 ? 1e6 * u(rng) : u(rng);
  }
  w[static_cast<size_t>(n) / 2] += 1.0;  // never all zero
  return w;
}

// The quantisation as first written (stable sort of all cells, cyclic hand-out), kept here as
// the oracle that the faster selection in quantise_masses gives the same bytes.
std::vector<std::uint16_t> reference_quantise(const WavelengthDistribution& d) {
  constexpr double kTotal = 65535;
  const int n = d.cells();
  std::vector<std::int64_t> q(static_cast<size_t>(n));
  std::vector<double> remainder(static_cast<size_t>(n), 0.0);
  std::int64_t sum = 0;
  for (int i = 0; i < n; ++i) {
    if (d.cell_mass(i) <= 0.0) continue;
    const double m = d.cell_mass(i) * kTotal;
    q[i] = std::max<std::int64_t>(1, static_cast<std::int64_t>(std::floor(m)));
    remainder[i] = m - static_cast<double>(q[i]);
    sum += q[i];
  }
  std::vector<int> order(static_cast<size_t>(n));
  std::iota(order.begin(), order.end(), 0);
  std::stable_sort(order.begin(), order.end(),
                   [&](int a, int b) { return remainder[a] > remainder[b]; });
  for (size_t k = 0; sum < static_cast<std::int64_t>(kTotal); k = (k + 1) % order.size()) {
    if (d.cell_mass(order[k]) > 0.0) {
      ++q[order[k]];
      ++sum;
    }
  }
  while (sum > static_cast<std::int64_t>(kTotal)) {
    const int big = static_cast<int>(std::max_element(q.begin(), q.end()) - q.begin());
    --q[big];
    --sum;
  }
  std::vector<std::uint16_t> cdf(static_cast<size_t>(n) + 1);
  std::int64_t running = 0;
  for (int i = 0; i < n; ++i) {
    running += q[i];
    cdf[i + 1] = static_cast<std::uint16_t>(running);
  }
  return cdf;
}

TEST(PixelTablesTest, QuantiseWeightsGivesTheBytesOfFromTable) {
  std::mt19937_64 rng(11);
  WavelengthDistribution::QuantiseScratch scratch;  // reused across sizes on purpose
  for (int n : {1, 2, 4, 64, 470, 64, 256, 3}) {
    for (int rep = 0; rep < 50; ++rep) {
      const std::vector<double> w = random_weights(n, rng);
      std::vector<std::uint16_t> got(static_cast<size_t>(n) + 1);
      WavelengthDistribution::quantise_weights(w, got, scratch);
      const WavelengthDistribution d = *WavelengthDistribution::from_table(w);
      EXPECT_EQ(got, d.quantise()) << n << " " << rep;
      EXPECT_EQ(got, reference_quantise(d)) << n << " " << rep;
    }
  }
  // Equal weights give (nearly) equal remainders: ties must resolve as the stable sort did.
  for (int n : {3, 7, 64, 100}) {
    const std::vector<double> flat(static_cast<size_t>(n), 1.0);
    std::vector<std::uint16_t> got(static_cast<size_t>(n) + 1);
    WavelengthDistribution::quantise_weights(flat, got, scratch);
    EXPECT_EQ(got, WavelengthDistribution::from_table(flat)->quantise()) << n;
    EXPECT_EQ(got, reference_quantise(*WavelengthDistribution::from_table(flat))) << n;
  }
}

TEST(PixelTablesTest, BytesAreLittleEndianWithoutTheLeadingZero) {
  const std::vector<std::uint16_t> cdf = {0, 0x0102, 0xa0b0, 65535};
  std::string out;
  append_pixel_table(cdf, out);
  append_default_pixel(3, out);
  ASSERT_EQ(out.size(), pixel_table_bytes(2, 1, 3));
  const std::string want("\x02\x01\xb0\xa0\xff\xff\0\0\0\0\0\0", 12);
  EXPECT_EQ(out, want);
  absl::StatusOr<PixelTables> t = PixelTables::decode(2, 1, 3, out);
  ASSERT_TRUE(t.ok()) << t.status();
  ASSERT_NE(t->table(0, 0), nullptr);
  EXPECT_TRUE(t->uses_default(1, 0));
  EXPECT_EQ(t->default_pixels(), 1);
  const double w = kLambdaRange / 3.0;
  EXPECT_EQ(t->table(0, 0)->cell_pdf(0), static_cast<float>(0x0102 / 65535.0 / w));
  EXPECT_EQ(t->table(0, 0)->cell_pdf(2), static_cast<float>((65535 - 0xa0b0) / 65535.0 / w));
}

TEST(PixelTablesTest, RoundTripSamplesExactlyLikeTheCoordinatorsTables) {
  constexpr int kW = 5, kH = 3, kCells = 64;
  std::mt19937_64 rng(5);
  std::vector<std::vector<std::uint16_t>> tables;
  std::string bytes;
  for (int p = 0; p < kW * kH; ++p) {
    if (p % 4 == 1) {
      tables.emplace_back();
      append_default_pixel(kCells, bytes);
      continue;
    }
    tables.push_back(WavelengthDistribution::from_table(random_weights(kCells, rng))->quantise());
    append_pixel_table(tables.back(), bytes);
  }
  absl::StatusOr<PixelTables> decoded = PixelTables::decode(kW, kH, kCells, bytes);
  ASSERT_TRUE(decoded.ok()) << decoded.status();
  // Moving keeps the views valid (they point into the moved heap buffer).
  const PixelTables t = std::move(*decoded);
  EXPECT_EQ(t.default_pixels(), 4);
  std::uniform_real_distribution<double> u(0.0, 1.0);
  for (int p = 0; p < kW * kH; ++p) {
    const QuantisedWavelengthCdf* got = t.table(p % kW, p / kW);
    if (tables[p].empty()) {
      EXPECT_EQ(got, nullptr) << p;
      continue;
    }
    ASSERT_NE(got, nullptr) << p;
    const QuantisedWavelengthCdf want = *QuantisedWavelengthCdf::create(tables[p]);
    for (int i = 0; i < 50; ++i) {
      const double v = u(rng);
      const SampledWavelengths a = got->sample_lanes(v, 4), b = want.sample_lanes(v, 4);
      for (int s = 0; s < 4; ++s) {
        ASSERT_EQ(a.lambda(s), b.lambda(s));
        ASSERT_EQ(a.pdf(s), b.pdf(s));
        ASSERT_EQ(got->pdf(a.lambda(s)), a.pdf(s));
      }
    }
  }
}

TEST(PixelTablesTest, ViewsSampleExactlyLikeWhatTheyView) {
  const WavelengthDistribution job_default = *WavelengthDistribution::visible(470);
  std::mt19937_64 rng(9);
  const std::vector<std::uint16_t> cdf =
      WavelengthDistribution::from_table(random_weights(64, rng))->quantise();
  std::string bytes;
  append_pixel_table(cdf, bytes);
  append_default_pixel(64, bytes);
  const PixelTables t = *PixelTables::decode(2, 1, 64, bytes);
  const BinnedShape shape = *BinnedShape::create(job_default, 64);
  const WavelengthPdfView table_view = t.view(0, 0, job_default, shape);
  const WavelengthPdfView default_view = t.view(1, 0, job_default, shape);
  EXPECT_TRUE(table_view.is_pixel_table());
  EXPECT_FALSE(default_view.is_pixel_table());
  const QuantisedWavelengthCdf& q = *t.table(0, 0);
  std::uniform_real_distribution<double> u(0.0, 1.0);
  for (int i = 0; i < 200; ++i) {
    const double v = u(rng);
    const SampledWavelengths a = table_view.sample_lanes(v, 4), b = shape.sample_lanes(q, v, 4);
    const SampledWavelengths c = default_view.sample_lanes(v, 4),
                             d = job_default.sample_lanes(v, 4);
    for (int s = 0; s < 4; ++s) {
      ASSERT_EQ(a.lambda(s), b.lambda(s));
      ASSERT_EQ(a.pdf(s), b.pdf(s));
      ASSERT_EQ(c.lambda(s), d.lambda(s));
      ASSERT_EQ(c.pdf(s), d.pdf(s));
    }
    const float l = static_cast<float>(kLambdaMin + v * kLambdaRange);
    ASSERT_EQ(table_view.pdf(l), shape.pdf(q, l));
    ASSERT_EQ(default_view.pdf(l), job_default.pdf(l));
    ASSERT_EQ(table_view.cdf(l), shape.cdf(q, l));
    ASSERT_EQ(default_view.sample(v).lambda, job_default.sample(v).lambda);
  }
  // The implicit conversion lets existing callers pass the job's distribution unchanged.
  const auto takes_view = [](WavelengthPdfView view) { return view.pdf(550.0f); };
  EXPECT_EQ(takes_view(job_default), job_default.pdf(550.0f));
}

TEST(PixelTablesTest, DecodeRefusesMalformedTables) {
  const std::vector<std::uint16_t> good = {0, 100, 65535};
  std::string bytes;
  append_pixel_table(good, bytes);
  append_pixel_table(good, bytes);
  EXPECT_TRUE(PixelTables::decode(2, 1, 2, bytes).ok());

  absl::Status s = PixelTables::decode(2, 2, 2, bytes).status();
  EXPECT_EQ(s.code(), absl::StatusCode::kInvalidArgument);
  EXPECT_NE(std::string(s.message()).find("need 16 bytes"), std::string::npos) << s;
  EXPECT_NE(std::string(s.message()).find("got 8"), std::string::npos) << s;
  s = PixelTables::decode(2, 1, 2, bytes.substr(1)).status();
  EXPECT_EQ(s.code(), absl::StatusCode::kInvalidArgument);
  EXPECT_FALSE(PixelTables::decode(0, 1, 2, "").ok());
  EXPECT_FALSE(PixelTables::decode(1, 1, 0, "").ok());

  // Second pixel decreasing: named by its position.
  std::string bad = bytes;
  bad[4] = '\xff';
  bad[5] = '\xff';
  bad[6] = '\x01';
  bad[7] = '\x00';
  s = PixelTables::decode(2, 1, 2, bad).status();
  EXPECT_EQ(s.code(), absl::StatusCode::kInvalidArgument);
  EXPECT_NE(std::string(s.message()).find("(1, 0)"), std::string::npos) << s;
  // Not ending at 65535.
  bad = bytes;
  bad[2] = '\x00';
  bad[3] = '\x10';
  s = PixelTables::decode(2, 1, 2, bad).status();
  EXPECT_NE(std::string(s.message()).find("(0, 0)"), std::string::npos) << s;
}

// Chi-square of every CMIS lane's marginal against the decoded table's own pdf: the expected
// counts come from the quantised integers, so quantisation is part of what is tested. Three
// histogram cells per table cell also test the uniform placement inside a cell.
TEST(PixelTablesTest, DecodedTablesSampleTheirQuantisedPdf) {
  constexpr int kSamples = 120000;
  constexpr int kSub = 3;
  std::mt19937_64 rng(17);
  std::vector<std::vector<double>> weights;
  for (int rep = 0; rep < 3; ++rep) weights.push_back(random_weights(64, rng));
  // Very peaked: one cell holds all but ~1e-9 of the mass, the rest is tiny but positive.
  std::vector<double> peak(64, 1e-9);
  peak[40] = 1.0;
  weights.push_back(peak);
  // A line spectrum on a fine grid with a zero-mass background.
  std::vector<double> lines(470, 0.0);
  lines[76] = 1.0;   // 436 nm
  lines[186] = 3.0;  // 546 nm
  lines[251] = 0.5;  // 611 nm
  weights.push_back(lines);
  const double threshold = testing::sidak_threshold(1e-4, int(weights.size()) * 4);

  std::string bytes;
  for (const std::vector<double>& w : weights) {
    bytes.clear();
    const int cells = int(w.size());
    append_pixel_table(WavelengthDistribution::from_table(w)->quantise(), bytes);
    const absl::StatusOr<PixelTables> t = PixelTables::decode(1, 1, cells, bytes);
    ASSERT_TRUE(t.ok()) << t.status();
    const QuantisedWavelengthCdf& q = *t->table(0, 0);
    const double width = kLambdaRange / double(cells);
    for (int lane = 0; lane < 4; ++lane) {
      std::vector<double> observed(size_t(cells) * kSub, 0.0), expected(observed.size(), 0.0);
      std::uniform_real_distribution<double> u(0.0, 1.0);
      for (int i = 0; i < kSamples; ++i) {
        const SampledWavelengths s = q.sample_lanes(u(rng), 4);
        const float l = s.lambda(lane);
        ASSERT_GT(s.pdf(lane), 0.0f) << l;
        ASSERT_EQ(s.pdf(lane), q.pdf(l)) << l;
        const double x = (double(l) - kLambdaMin) / width;
        const int c = std::min(cells - 1, int(x));
        const int sub = std::min(kSub - 1, int((x - c) * kSub));
        observed[size_t(c) * kSub + sub] += 1.0;
      }
      for (int c = 0; c < cells; ++c) {
        const double mass = double(q.cell_pdf(c)) * width;
        for (int sub = 0; sub < kSub; ++sub)
          expected[size_t(c) * kSub + sub] = kSamples * mass / kSub;
      }
      const testing::ChiSquareResult r = testing::chi_square(observed, expected);
      EXPECT_GT(r.p_value, threshold) << cells << " cells, lane " << lane << ": " << r.describe();
    }
  }
}

}  // namespace
}  // namespace prism::spectral
