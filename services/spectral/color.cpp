#include "services/spectral/color.h"

#include <cmath>

#include "absl/strings/str_cat.h"
#include "services/base/check.h"
#include "services/base/status.h"
#include "services/spectral/csv_table.h"
#include "services/spectral/embedded_data.h"

namespace prism::spectral {
namespace {

using Mat3 = std::array<std::array<double, 3>, 3>;
using Vec3 = std::array<double, 3>;

constexpr Mat3 mul(const Mat3& a, const Mat3& b) {
  Mat3 r{};
  for (int i = 0; i < 3; ++i)
    for (int j = 0; j < 3; ++j)
      for (int k = 0; k < 3; ++k) r[i][j] += a[i][k] * b[k][j];
  return r;
}

constexpr Vec3 mul(const Mat3& m, const Vec3& v) {
  return {m[0][0] * v[0] + m[0][1] * v[1] + m[0][2] * v[2],
          m[1][0] * v[0] + m[1][1] * v[1] + m[1][2] * v[2],
          m[2][0] * v[0] + m[2][1] * v[1] + m[2][2] * v[2]};
}

constexpr Mat3 inverse(const Mat3& m) {
  const double det = m[0][0] * (m[1][1] * m[2][2] - m[1][2] * m[2][1]) -
                     m[0][1] * (m[1][0] * m[2][2] - m[1][2] * m[2][0]) +
                     m[0][2] * (m[1][0] * m[2][1] - m[1][1] * m[2][0]);
  const double inv = 1.0 / det;
  return {{{(m[1][1] * m[2][2] - m[1][2] * m[2][1]) * inv,
            (m[0][2] * m[2][1] - m[0][1] * m[2][2]) * inv,
            (m[0][1] * m[1][2] - m[0][2] * m[1][1]) * inv},
           {(m[1][2] * m[2][0] - m[1][0] * m[2][2]) * inv,
            (m[0][0] * m[2][2] - m[0][2] * m[2][0]) * inv,
            (m[0][2] * m[1][0] - m[0][0] * m[1][2]) * inv},
           {(m[1][0] * m[2][1] - m[1][1] * m[2][0]) * inv,
            (m[0][1] * m[2][0] - m[0][0] * m[2][1]) * inv,
            (m[0][0] * m[1][1] - m[0][1] * m[1][0]) * inv}}};
}

constexpr Vec3 xy_to_xyz(double x, double y) {
  return {x / y, 1.0, (1.0 - x - y) / y};
}

// RGB → XYZ for primaries r, g, b and white w given as (x, y): columns are the primaries' XYZ
// scaled so that RGB (1, 1, 1) is the white with Y = 1.
constexpr Mat3 rgb_to_xyz(const Vec3& r, const Vec3& g, const Vec3& b, const Vec3& w) {
  const Mat3 p = {{{r[0], g[0], b[0]}, {r[1], g[1], b[1]}, {r[2], g[2], b[2]}}};
  const Vec3 s = mul(inverse(p), w);
  return {{{p[0][0] * s[0], p[0][1] * s[1], p[0][2] * s[2]},
           {p[1][0] * s[0], p[1][1] * s[1], p[1][2] * s[2]},
           {p[2][0] * s[0], p[2][1] * s[1], p[2][2] * s[2]}}};
}

constexpr Vec3 kD65White = xy_to_xyz(0.3127, 0.3290);
constexpr Vec3 kAcesWhite = xy_to_xyz(0.32168, 0.33767);

constexpr Mat3 kSrgbToXyz =
    rgb_to_xyz(xy_to_xyz(0.64, 0.33), xy_to_xyz(0.30, 0.60), xy_to_xyz(0.15, 0.06), kD65White);
constexpr Mat3 kXyzToSrgb = inverse(kSrgbToXyz);

constexpr Mat3 kBradford = {
    {{0.8951, 0.2664, -0.1614}, {-0.7502, 1.7135, 0.0367}, {0.0389, -0.0685, 1.0296}}};

constexpr Mat3 bradford(const Vec3& from, const Vec3& to) {
  const Vec3 f = mul(kBradford, from);
  const Vec3 t = mul(kBradford, to);
  const Mat3 scale = {{{t[0] / f[0], 0, 0}, {0, t[1] / f[1], 0}, {0, 0, t[2] / f[2]}}};
  return mul(inverse(kBradford), mul(scale, kBradford));
}

constexpr Mat3 kAp1ToXyz = rgb_to_xyz(xy_to_xyz(0.713, 0.293), xy_to_xyz(0.165, 0.830),
                                      xy_to_xyz(0.128, 0.044), kAcesWhite);
constexpr Mat3 kXyzD65ToAcescg = mul(inverse(kAp1ToXyz), bradford(kD65White, kAcesWhite));

constexpr int kCmfSamples = 471;  // 360..830 nm at 1 nm

}  // namespace

Xyz XyzBinWeights::to_xyz(std::span<const float> bin_values) const {
  PRISM_CHECK(static_cast<int>(bin_values.size()) == grid_.bins());
  Xyz r;
  for (size_t b = 0; b < bin_values.size(); ++b) {
    r.x += bin_values[b] * weights_[b].x;
    r.y += bin_values[b] * weights_[b].y;
    r.z += bin_values[b] * weights_[b].z;
  }
  return r;
}

ColorMatching ColorMatching::cie1931() {
  constexpr std::string_view kPath = "cmf/cie1931_2deg_xyz_cmf_360_830_1nm.csv";
  auto table = parse_csv_table(embedded_file(kPath), kPath);
  PRISM_CHECK(table.ok());
  ColorMatching cm;
  auto lambda = table->numeric_column(0);
  PRISM_CHECK(lambda.ok() && static_cast<int>(lambda->size()) == kCmfSamples);
  cm.table_.resize(kCmfSamples);
  for (int c = 0; c < 3; ++c) {
    auto values = table->numeric_column(c + 1);
    PRISM_CHECK(values.ok());
    for (int i = 0; i < kCmfSamples; ++i) {
      PRISM_CHECK((*lambda)[i] == kLambdaMin + i);
      cm.table_[i][c] = (*values)[i];
    }
    auto curve = PiecewiseLinearSpectrum::create(*lambda, *values, kPath);
    PRISM_CHECK(curve.ok());
    cm.curves_.push_back(*std::move(curve));
    if (c == 1) {
      for (double v : *values) cm.y_sum_ += v;
    }
  }
  cm.srgb_table_.resize(kCmfSamples);
  for (int i = 0; i < kCmfSamples; ++i) {
    const Rgb c = xyz_to_linear_srgb({cm.table_[i][0], cm.table_[i][1], cm.table_[i][2]});
    cm.srgb_table_[i] = {c.r, c.g, c.b};
  }
  return cm;
}

Xyz ColorMatching::cmf(float lambda_nm) const {
  if (!(lambda_nm >= kLambdaMin && lambda_nm <= kLambdaMax)) return {};
  const float f = lambda_nm - kLambdaMin;
  const int i = std::min(static_cast<int>(f), kCmfSamples - 2);
  const double t = f - static_cast<float>(i);
  const auto& a = table_[i];
  const auto& b = table_[i + 1];
  return {a[0] + t * (b[0] - a[0]), a[1] + t * (b[1] - a[1]), a[2] + t * (b[2] - a[2])};
}

Rgb ColorMatching::srgb(float lambda_nm) const {
  if (!(lambda_nm >= kLambdaMin && lambda_nm <= kLambdaMax)) return {};
  const float f = lambda_nm - kLambdaMin;
  const int i = std::min(static_cast<int>(f), kCmfSamples - 2);
  const double t = f - static_cast<float>(i);
  const auto& a = srgb_table_[i];
  const auto& b = srgb_table_[i + 1];
  return {a[0] + t * (b[0] - a[0]), a[1] + t * (b[1] - a[1]), a[2] + t * (b[2] - a[2])};
}

Xyz ColorMatching::to_xyz(const Spectrum& s) const {
  Xyz r;
  for (int i = 0; i < kCmfSamples; ++i) {
    const double v = eval(s, kLambdaMin + static_cast<float>(i));
    r.x += table_[i][0] * v;
    r.y += table_[i][1] * v;
    r.z += table_[i][2] * v;
  }
  r.x /= kCieYIntegral;
  r.y /= kCieYIntegral;
  r.z /= kCieYIntegral;
  return r;
}

double ColorMatching::photometric_sum(const Spectrum& s) const {
  double sum = 0.0;
  for (int i = 0; i < kCmfSamples; ++i) {
    sum += table_[i][1] * eval(s, kLambdaMin + static_cast<float>(i));
  }
  return sum;
}

XyzBinWeights ColorMatching::bin_weights(const WavelengthGrid& grid) const {
  std::vector<Xyz> w(static_cast<size_t>(grid.bins()));
  for (int b = 0; b < grid.bins(); ++b) {
    w[b] = {curves_[0].integral(grid.lower(b), grid.upper(b)) / kCieYIntegral,
            curves_[1].integral(grid.lower(b), grid.upper(b)) / kCieYIntegral,
            curves_[2].integral(grid.lower(b), grid.upper(b)) / kCieYIntegral};
  }
  return XyzBinWeights(grid, std::move(w));
}

absl::StatusOr<PiecewiseLinearSpectrum> cie_daylight_illuminant(std::string_view name) {
  // The nominal temperatures, corrected for the change of c2 in Planck's law (1.4380e-2 to
  // 1.4388e-2 m·K) as CIE 015 defines D50 ... D75.
  double nominal = 0.0;
  for (const auto& [n, t] : {std::pair<std::string_view, double>{"D50", 5000.0},
                             {"D55", 5500.0},
                             {"D65", 6500.0},
                             {"D75", 7500.0}}) {
    if (n == name) nominal = t;
  }
  if (nominal == 0.0) {
    return absl::InvalidArgumentError(absl::StrCat(
        "no CIE daylight illuminant '", absl::string_view(name.data(), name.size()), "'"));
  }
  const double t = nominal * 1.4388 / 1.4380;
  // CIE 015:2018 eq. 4.1 and 4.2: the daylight locus, then the basis weights.
  const double x = t <= 7000.0
                       ? -4.6070e9 / (t * t * t) + 2.9678e6 / (t * t) + 0.09911e3 / t + 0.244063
                       : -2.0064e9 / (t * t * t) + 1.9018e6 / (t * t) + 0.24748e3 / t + 0.237040;
  const double y = -3.000 * x * x + 2.870 * x - 0.275;
  const double m = 0.0241 + 0.2562 * x - 0.7341 * y;
  const double m1 = std::round((-1.3515 - 1.7703 * x + 5.9114 * y) / m * 1000.0) / 1000.0;
  const double m2 = std::round((0.0300 - 31.4424 * x + 30.0717 * y) / m * 1000.0) / 1000.0;

  constexpr std::string_view kTablePath = "illuminants/cie_standard_illuminants_300_780_5nm.csv";
  constexpr std::string_view kBasisPath = "illuminants/cie_daylight_basis_S0_S1_S2_300_830_5nm.csv";
  PRISM_ASSIGN_OR_RETURN(const CsvTable table,
                         parse_csv_table(embedded_file(kTablePath), kTablePath));
  PRISM_ASSIGN_OR_RETURN(const CsvTable basis,
                         parse_csv_table(embedded_file(kBasisPath), kBasisPath));
  PRISM_ASSIGN_OR_RETURN(std::vector<double> lambda, table.numeric_column(0));
  PRISM_ASSIGN_OR_RETURN(std::vector<double> value, table.numeric_column(name));
  PRISM_ASSIGN_OR_RETURN(const std::vector<double> basis_lambda, basis.numeric_column(0));
  PRISM_ASSIGN_OR_RETURN(const std::vector<double> s0, basis.numeric_column("S0"));
  PRISM_ASSIGN_OR_RETURN(const std::vector<double> s1, basis.numeric_column("S1"));
  PRISM_ASSIGN_OR_RETURN(const std::vector<double> s2, basis.numeric_column("S2"));
  const double table_end = lambda.back();
  for (std::size_t i = 0; i < basis_lambda.size(); ++i) {
    if (basis_lambda[i] <= table_end) continue;
    lambda.push_back(basis_lambda[i]);
    value.push_back(s0[i] + m1 * s1[i] + m2 * s2[i]);
  }
  return PiecewiseLinearSpectrum::create(lambda, value, kTablePath);
}

PiecewiseLinearSpectrum cie_d65() {
  absl::StatusOr<PiecewiseLinearSpectrum> d65 = cie_daylight_illuminant("D65");
  PRISM_CHECK(d65.ok());
  return *std::move(d65);
}

Rgb xyz_to_linear_srgb(const Xyz& xyz) {
  const Vec3 v = mul(kXyzToSrgb, Vec3{xyz.x, xyz.y, xyz.z});
  return {v[0], v[1], v[2]};
}

Xyz linear_srgb_to_xyz(const Rgb& rgb) {
  const Vec3 v = mul(kSrgbToXyz, Vec3{rgb.r, rgb.g, rgb.b});
  return {v[0], v[1], v[2]};
}

Rgb xyz_to_acescg(const Xyz& xyz) {
  const Vec3 v = mul(kXyzD65ToAcescg, Vec3{xyz.x, xyz.y, xyz.z});
  return {v[0], v[1], v[2]};
}

double srgb_encode(double linear) {
  const double a = std::abs(linear);
  const double e = a <= 0.0031308 ? 12.92 * a : 1.055 * std::pow(a, 1.0 / 2.4) - 0.055;
  return std::copysign(e, linear);
}

double srgb_decode(double encoded) {
  const double a = std::abs(encoded);
  const double l = a <= 0.04045 ? a / 12.92 : std::pow((a + 0.055) / 1.055, 2.4);
  return std::copysign(l, encoded);
}

Lab xyz_to_lab(const Xyz& xyz, const Xyz& white) {
  constexpr double kDelta = 6.0 / 29.0;
  auto f = [](double t) {
    return t > kDelta * kDelta * kDelta ? std::cbrt(t) : t / (3.0 * kDelta * kDelta) + 4.0 / 29.0;
  };
  const double fx = f(xyz.x / white.x), fy = f(xyz.y / white.y), fz = f(xyz.z / white.z);
  return {116.0 * fy - 16.0, 500.0 * (fx - fy), 200.0 * (fy - fz)};
}

}  // namespace prism::spectral
