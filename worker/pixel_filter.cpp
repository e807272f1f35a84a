#include "worker/pixel_filter.h"

#include <algorithm>
#include <cmath>
#include <numbers>

#include "absl/strings/str_cat.h"
#include "services/base/cdf_guide.h"

namespace prism::worker {
namespace {

constexpr int kCellsPerPixel = 64;
constexpr int kSimpsonPanels = 16;  // even

double sinc(double x) {
  const double a = std::numbers::pi * x;
  return std::abs(a) < 1e-7 ? 1.0 - a * a / 6.0 : std::sin(a) / a;
}

// pbrt-v4's Mitchell1D on x in [-2, 2] (its filter evaluates it at 2·offset/radius).
double mitchell(double x, double b, double c) {
  x = std::abs(x);
  if (x <= 1) {
    return ((12 - 9 * b - 6 * c) * x * x * x + (-18 + 12 * b + 6 * c) * x * x + (6 - 2 * b)) / 6;
  }
  if (x <= 2) {
    return ((-b - 6 * c) * x * x * x + (6 * b + 30 * c) * x * x + (-12 * b - 48 * c) * x +
            (8 * b + 24 * c)) /
           6;
  }
  return 0;
}

// ∫ g over [a, b] by Simpson's rule with kSimpsonPanels panels.
template <typename F>
double simpson(F&& g, double a, double b) {
  const double h = (b - a) / kSimpsonPanels;
  double sum = g(a) + g(b);
  for (int i = 1; i < kSimpsonPanels; ++i) sum += g(a + i * h) * (i % 2 == 1 ? 4 : 2);
  return sum * h / 3;
}

}  // namespace

double PixelFilter::Axis::evaluate(double x) const {
  if (std::abs(x) > radius) return 0;
  switch (type) {
    case scene::PixelFilterType::kBox:
      return 1;
    case scene::PixelFilterType::kGaussian:
      return std::max(0.0, std::exp(-x * x * inverse_two_sigma2) - gaussian_floor);
    case scene::PixelFilterType::kTriangle:
      return std::max(0.0, radius - std::abs(x));
    case scene::PixelFilterType::kMitchell:
      return mitchell(2 * x / radius, b, c);
    case scene::PixelFilterType::kLanczos:
      return sinc(x) * sinc(x / tau);
  }
  return 0;
}

void PixelFilter::Axis::sample(double u, double* x, double* weight) const {
  if (type == scene::PixelFilterType::kBox) {
    *x = radius * (2 * u - 1);
    *weight = 1;
    return;
  }
  const int cells = int(cdf.size()) - 2;
  // The cell whose CDF interval holds u (cells of zero mass are never chosen); u below 1, which
  // the guided search needs (the sampler's numbers are).
  u = std::min(u, 0x1.fffffffffffffp-1);
  const int cell = base::guided_cell(std::span<const double>(cdf), std::span<const int>(guide), u);
  const double mass = cdf[cell + 1] - cdf[cell];
  const double width = 2 * radius / cells;
  const double t = mass > 0 ? std::clamp((u - cdf[cell]) / mass, 0.0, 1.0) : 0.5;
  *x = -radius + (cell + t) * width;
  // The cell's share of ∫|f| spread evenly over it: a density that integrates to 1.
  const double pdf = mass / width;
  *weight = pdf > 0 ? evaluate(*x) / (pdf * integral) : 0;
}

PixelFilter::Axis PixelFilter::make_axis(const scene::PixelFilterSpec& spec, double radius) {
  Axis a;
  a.type = spec.type;
  a.radius = radius;
  a.sigma = spec.sigma;
  a.b = spec.b;
  a.c = spec.c;
  a.tau = spec.tau;
  a.inverse_two_sigma2 = 1.0 / (2.0 * spec.sigma * spec.sigma);
  a.gaussian_floor = std::exp(-radius * radius * a.inverse_two_sigma2);
  if (a.type == scene::PixelFilterType::kBox) {
    a.integral = a.abs_integral = 2 * radius;
    return a;
  }
  const int cells = std::max(8, int(std::ceil(2 * radius * kCellsPerPixel)));
  const double width = 2 * radius / cells;
  std::vector<double> masses(static_cast<std::size_t>(cells));
  a.integral = 0;
  a.abs_integral = 0;
  for (int i = 0; i < cells; ++i) {
    const double lo = -radius + i * width, hi = lo + width;
    a.integral += simpson([&](double x) { return a.evaluate(x); }, lo, hi);
    masses[i] = simpson([&](double x) { return std::abs(a.evaluate(x)); }, lo, hi);
    a.abs_integral += masses[i];
  }
  a.cdf.assign(static_cast<std::size_t>(cells) + 2, 0.0);
  for (int i = 0; i < cells; ++i) a.cdf[i + 1] = a.cdf[i] + masses[i] / a.abs_integral;
  a.cdf[cells] = a.cdf[cells + 1] = 1.0;  // the last value, and cdf_guide.h's sentinel
  base::build_cdf_guide(std::span<const double>(a.cdf), a.guide);
  return a;
}

absl::StatusOr<PixelFilter> PixelFilter::create(const scene::PixelFilterSpec& spec) {
  for (double r : {spec.x_radius, spec.y_radius}) {
    if (!(r >= 0.01 && r <= 16)) {
      return absl::InvalidArgumentError(
          absl::StrCat("pixel filter radius ", r, " is outside 0.01..16 pixels"));
    }
  }
  if (spec.type == scene::PixelFilterType::kGaussian &&
      !(spec.sigma >= 1e-3 && spec.sigma <= 1e3)) {
    return absl::InvalidArgumentError(
        absl::StrCat("gaussian pixel filter sigma ", spec.sigma, " is outside 0.001..1000"));
  }
  if (spec.type == scene::PixelFilterType::kLanczos && !(spec.tau >= 1e-3 && spec.tau <= 1e3)) {
    return absl::InvalidArgumentError(
        absl::StrCat("lanczos pixel filter tau ", spec.tau, " is outside 0.001..1000"));
  }
  PixelFilter f;
  f.axes_[0] = make_axis(spec, spec.x_radius);
  f.axes_[1] = make_axis(spec, spec.y_radius);
  for (const Axis& a : f.axes_) {
    if (!(std::abs(a.integral) > 1e-9 * a.abs_integral) || !std::isfinite(a.integral)) {
      return absl::InvalidArgumentError(
          "pixel filter integrates to 0: its parameters leave no positive weight");
    }
  }
  f.unit_box_ =
      spec.type == scene::PixelFilterType::kBox && spec.x_radius == 0.5 && spec.y_radius == 0.5;
  return f;
}

FilterSample PixelFilter::sample(float u0, float u1) const {
  if (unit_box_) return {u0, u1, 1.0f};
  double x = 0, y = 0, wx = 1, wy = 1;
  axes_[0].sample(u0, &x, &wx);
  axes_[1].sample(u1, &y, &wy);
  return {static_cast<float>(0.5 + x), static_cast<float>(0.5 + y), static_cast<float>(wx * wy)};
}

double PixelFilter::evaluate(double dx, double dy) const {
  return axes_[0].evaluate(dx) * axes_[1].evaluate(dy);
}

}  // namespace prism::worker
