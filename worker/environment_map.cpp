#include "worker/environment_map.h"

#include <algorithm>
#include <cmath>
#include <numbers>

#include "absl/strings/str_cat.h"
#include "services/base/status.h"
#include "worker/equal_area.h"

namespace prism::worker {

absl::StatusOr<IlluminantTexels> IlluminantTexels::create(const scene::TextureImage& image,
                                                          const spectral::RgbUplift& uplift) {
  IlluminantTexels out;
  const size_t texels = size_t(image.width) * size_t(image.height);
  out.scale.resize(texels);
  out.polynomial.resize(texels);
  out.brightness.resize(texels);
  double sum[3] = {0, 0, 0};
  for (size_t i = 0; i < texels; ++i) {
    float rgb[3];
    for (int c = 0; c < 3; ++c) {
      const int channel = image.channels == 1 ? 0 : c;
      rgb[c] = std::max(0.0f, image.values[i * size_t(image.channels) + size_t(channel)]);
      sum[c] += rgb[c];
    }
    PRISM_ASSIGN_OR_RETURN(spectral::RgbIlluminantSpectrum s,
                           uplift.illuminant({rgb[0], rgb[1], rgb[2]}));
    if (!out.illuminant) out.illuminant = s.illuminant;
    out.scale[i] = s.scale;
    out.polynomial[i] = s.polynomial;
    out.brightness[i] = (rgb[0] + rgb[1] + rgb[2]) / 3;
  }
  out.mean = {sum[0] / double(texels), sum[1] / double(texels), sum[2] / double(texels)};
  return out;
}

spectral::SampledSpectrum IlluminantTexels::at(size_t texel,
                                               const spectral::SampledWavelengths& lambda) const {
  spectral::SampledSpectrum out;
  if (scale[texel] == 0) return out;
  for (int s = 0; s < lambda.count(); ++s) {
    const float l = lambda.lambda(s);
    out[s] = scale[texel] * polynomial[texel](l) * (*illuminant)(l);
  }
  return out;
}

absl::StatusOr<std::shared_ptr<const EnvironmentMap>> EnvironmentMap::create(
    const scene::TextureImage& image, const scene::Transform& light_to_world,
    const spectral::RgbUplift& uplift) {
  if (image.width != image.height || image.width < 1) {
    return absl::InvalidArgumentError(
        absl::StrCat("environment map is ", image.width, "x", image.height, "; it must be square"));
  }
  std::shared_ptr<EnvironmentMap> map(new EnvironmentMap());
  const int n = image.width;
  map->size_ = n;
  PRISM_ASSIGN_OR_RETURN(map->texels_, IlluminantTexels::create(image, uplift));
  const std::vector<float>& weight = map->texels_.brightness;

  map->row_cdf_.assign(size_t(n) + 1, 0.0);
  map->column_cdf_.assign(size_t(n) * (size_t(n) + 1), 0.0);
  for (int y = 0; y < n; ++y) {
    double* cdf = &map->column_cdf_[size_t(y) * (size_t(n) + 1)];
    for (int x = 0; x < n; ++x) cdf[x + 1] = cdf[x] + weight[size_t(y) * size_t(n) + x];
    map->row_cdf_[size_t(y) + 1] = map->row_cdf_[size_t(y)] + cdf[n];
  }
  map->total_ = map->row_cdf_[size_t(n)];

  // sRGB's luminance row (the Y of its RGB-to-XYZ matrix), as pbrt-v4 weighs texels.
  constexpr double kLuminance[3] = {0.2126729, 0.7151522, 0.0721750};
  // Each texel's mean of max(cos θ, 0) over sub x sub points: at least 64 x 64 over the whole
  // square, and 8 x 8 in texels the horizon crosses, so that a constant map's illuminance is
  // π·L within 0.2 % at every size.
  auto cosine = [n](double u, double v) {
    return std::max(
        0.0,
        double(equal_area_square_to_sphere(Point2f{float(u / double(n)), float(v / double(n))}).z));
  };
  const int interior_sub = std::max(1, 64 / n);
  double upper = 0;
  for (int y = 0; y < n; ++y) {
    for (int x = 0; x < n; ++x) {
      // The horizon is the inner diamond's edge, straight in the square: a texel is cut by it
      // when its corners disagree, or (a map of one texel, or three, whose texel holds a corner
      // of the diamond) when its centre is above and its corners are not.
      int above = 0;
      for (int corner = 0; corner < 4; ++corner)
        above += cosine(x + (corner & 1), y + (corner >> 1)) > 0;
      if (above == 0 && !(cosine(x + 0.5, y + 0.5) > 0)) continue;
      const int sub = above == 4 ? interior_sub : std::max(8, interior_sub);
      double mean_cos = 0;
      for (int j = 0; j < sub; ++j)
        for (int i = 0; i < sub; ++i) mean_cos += cosine(x + (i + 0.5) / sub, y + (j + 0.5) / sub);
      mean_cos /= double(sub) * double(sub);
      if (!(mean_cos > 0)) continue;
      const size_t texel = (size_t(y) * size_t(n) + size_t(x)) * size_t(image.channels);
      double luminance = 0;
      for (int c = 0; c < 3; ++c) {
        const float v = image.values[texel + size_t(image.channels == 1 ? 0 : c)];
        luminance += kLuminance[c] * double(std::max(0.0f, v));
      }
      upper += luminance * mean_cos;
    }
  }
  map->upper_illuminance_ = upper * 4.0 * std::numbers::pi / (double(n) * double(n));

  const scene::Matrix4& m = light_to_world.matrix();
  const scene::Matrix4& inv = light_to_world.inverse_matrix();
  for (int r = 0; r < 3; ++r) {
    for (int c = 0; c < 3; ++c) {
      map->world_from_light_[r][c] = float(m[r][c]);
      map->light_from_world_[r][c] = float(inv[r][c]);
    }
  }
  return std::shared_ptr<const EnvironmentMap>(std::move(map));
}

Vec3f EnvironmentMap::to_light(const Vec3f& w) const {
  const auto& m = light_from_world_;
  return normalize(Vec3f{m[0][0] * w.x + m[0][1] * w.y + m[0][2] * w.z,
                         m[1][0] * w.x + m[1][1] * w.y + m[1][2] * w.z,
                         m[2][0] * w.x + m[2][1] * w.y + m[2][2] * w.z});
}

Vec3f EnvironmentMap::to_world(const Vec3f& w) const {
  const auto& m = world_from_light_;
  return normalize(Vec3f{m[0][0] * w.x + m[0][1] * w.y + m[0][2] * w.z,
                         m[1][0] * w.x + m[1][1] * w.y + m[1][2] * w.z,
                         m[2][0] * w.x + m[2][1] * w.y + m[2][2] * w.z});
}

// pbrt-v4's nearest lookup: texel floor(uv · size), row 0 at the top of the file.
int EnvironmentMap::texel_of(const Vec3f& w_world) const {
  const Point2f uv = equal_area_sphere_to_square(to_light(w_world));
  const int x = std::clamp(int(uv.x * float(size_)), 0, size_ - 1);
  const int y = std::clamp(int(uv.y * float(size_)), 0, size_ - 1);
  return y * size_ + x;
}

spectral::SampledSpectrum EnvironmentMap::radiance(
    const Vec3f& w, const spectral::SampledWavelengths& lambda) const {
  return texels_.at(size_t(texel_of(w)), lambda);
}

std::optional<EnvironmentMap::Sample> EnvironmentMap::sample(Point2f u) const {
  if (!(total_ > 0)) return std::nullopt;
  auto pick = [](const double* cdf, int n, double target, double* fraction) {
    // The last entry with cdf[i] <= target < cdf[i + 1], skipping empty cells.
    int i = int(std::upper_bound(cdf, cdf + n + 1, target) - cdf) - 1;
    i = std::clamp(i, 0, n - 1);
    while (i > 0 && cdf[i + 1] == cdf[i]) --i;
    const double width = cdf[i + 1] - cdf[i];
    *fraction = width > 0 ? std::clamp((target - cdf[i]) / width, 0.0, 1.0) : 0.5;
    return i;
  };
  double fy = 0, fx = 0;
  const int y = pick(row_cdf_.data(), size_, double(u.y) * total_, &fy);
  const double* columns = &column_cdf_[size_t(y) * (size_t(size_) + 1)];
  const int x = pick(columns, size_, double(u.x) * columns[size_], &fx);
  const float weight = texels_.brightness[size_t(y) * size_t(size_) + size_t(x)];
  if (!(weight > 0)) return std::nullopt;
  const Point2f p{(float(x) + float(fx)) / float(size_), (float(y) + float(fy)) / float(size_)};
  Sample s;
  s.w = to_world(equal_area_square_to_sphere(p));
  s.pdf = float(double(weight) * double(size_) * double(size_) / total_) / (4 * kPi);
  return s;
}

float EnvironmentMap::pdf(const Vec3f& w) const {
  if (!(total_ > 0)) return 0;
  const float weight = texels_.brightness[size_t(texel_of(w))];
  return float(double(weight) * double(size_) * double(size_) / total_) / (4 * kPi);
}

}  // namespace prism::worker
