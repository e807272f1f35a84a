#include "services/image/metrics.h"

#include <cmath>
#include <cstdio>
#include <span>
#include <vector>

#include "absl/strings/str_cat.h"
#include "services/base/status.h"
#include "services/image/exr_spectral.h"

namespace prism::image {
namespace {

// A channel-interleaved float image without ownership.
struct View {
  std::span<const float> data;
  int width;
  int height;
  int channels;
  float at(int x, int y, int c) const { return data[(std::size_t(y) * width + x) * channels + c]; }
};

std::vector<double> gaussian_weights(int n) {
  std::vector<double> w(n);
  double centre = (n - 1) / 2.0;
  double total = 0.0;
  for (int i = 0; i < n; ++i) {
    w[i] = std::exp(-(i - centre) * (i - centre) / (2.0 * kSsimSigma * kSsimSigma));
    total += w[i];
  }
  for (double& v : w) v /= total;
  return w;
}

// Mean SSIM of one channel, x = test (already sanitised), y = reference, both w x h.
double ssim_channel(const std::vector<double>& x, const std::vector<double>& y, int w, int h,
                    double c1, double c2) {
  int wx = std::min(kSsimWindow, w);
  int wy = std::min(kSsimWindow, h);
  std::vector<double> gx = gaussian_weights(wx);
  std::vector<double> gy = gaussian_weights(wy);
  int ow = w - wx + 1;
  int oh = h - wy + 1;
  // Horizontal pass of the five moments: mu_x, mu_y, E[x^2], E[y^2], E[xy].
  std::vector<double> hx(std::size_t(ow) * h), hy(hx.size()), hxx(hx.size()), hyy(hx.size()),
      hxy(hx.size());
  for (int row = 0; row < h; ++row) {
    for (int col = 0; col < ow; ++col) {
      double sx = 0, sy = 0, sxx = 0, syy = 0, sxy = 0;
      for (int k = 0; k < wx; ++k) {
        double a = x[std::size_t(row) * w + col + k];
        double b = y[std::size_t(row) * w + col + k];
        sx += gx[k] * a;
        sy += gx[k] * b;
        sxx += gx[k] * a * a;
        syy += gx[k] * b * b;
        sxy += gx[k] * a * b;
      }
      std::size_t i = std::size_t(row) * ow + col;
      hx[i] = sx;
      hy[i] = sy;
      hxx[i] = sxx;
      hyy[i] = syy;
      hxy[i] = sxy;
    }
  }
  double total = 0.0;
  for (int row = 0; row < oh; ++row) {
    for (int col = 0; col < ow; ++col) {
      double mx = 0, my = 0, exx = 0, eyy = 0, exy = 0;
      for (int k = 0; k < wy; ++k) {
        std::size_t i = std::size_t(row + k) * ow + col;
        mx += gy[k] * hx[i];
        my += gy[k] * hy[i];
        exx += gy[k] * hxx[i];
        eyy += gy[k] * hyy[i];
        exy += gy[k] * hxy[i];
      }
      double vx = exx - mx * mx;
      double vy = eyy - my * my;
      double cxy = exy - mx * my;
      total += ((2 * mx * my + c1) * (2 * cxy + c2)) / ((mx * mx + my * my + c1) * (vx + vy + c2));
    }
  }
  return total / (double(ow) * oh);
}

absl::StatusOr<ErrorMetrics> compare_views(const View& test, const View& ref,
                                           const std::optional<Crop>& crop) {
  if (test.width != ref.width || test.height != ref.height || test.channels != ref.channels) {
    return absl::InvalidArgumentError(absl::StrCat(
        "cannot compare a ", test.width, "x", test.height, "x", test.channels,
        " test image with a ", ref.width, "x", ref.height, "x", ref.channels, " reference"));
  }
  TileRect region{0, 0, ref.width, ref.height};
  if (crop) {
    PRISM_ASSIGN_OR_RETURN(region, crop_rect(*crop, ref.width, ref.height));
  }
  int w = region.width();
  int h = region.height();
  std::size_t n = std::size_t(w) * h;

  ErrorMetrics m;
  m.channels = ref.channels;
  double largest = 0.0;
  for (int y = 0; y < h; ++y) {
    for (int x = 0; x < w; ++x) {
      for (int c = 0; c < ref.channels; ++c) {
        double r = ref.at(region.x0 + x, region.y0 + y, c);
        if (!std::isfinite(r)) {
          return absl::InvalidArgumentError(
              absl::StrCat("the reference has a non-finite value at pixel (", region.x0 + x, ",",
                           region.y0 + y, ") channel ", c));
        }
        largest = std::max(largest, std::abs(r));
      }
    }
  }
  double dynamic_range = largest > 0.0 ? largest : 1.0;
  double c1 = (kSsimK1 * dynamic_range) * (kSsimK1 * dynamic_range);
  double c2 = (kSsimK2 * dynamic_range) * (kSsimK2 * dynamic_range);

  std::uint64_t nonfinite = 0;
  double squared = 0.0;
  double relative = 0.0;
  double ssim = 0.0;
  std::vector<double> xs(n);
  std::vector<double> ys(n);
  for (int c = 0; c < ref.channels; ++c) {
    for (int y = 0; y < h; ++y) {
      for (int x = 0; x < w; ++x) {
        double r = ref.at(region.x0 + x, region.y0 + y, c);
        double t = test.at(region.x0 + x, region.y0 + y, c);
        if (!std::isfinite(t)) {
          ++nonfinite;
          t = 0.0;
        }
        double e = (t - r) * (t - r);
        squared += e;
        relative += e / (r * r + kRelMseEpsilon);
        xs[std::size_t(y) * w + x] = t;
        ys[std::size_t(y) * w + x] = r;
      }
    }
    ssim += ssim_channel(xs, ys, w, h, c1, c2);
  }
  double count = double(n) * ref.channels;
  m.mse = squared / count;
  m.rel_mse = relative / count;
  m.nonfinite_fraction = double(nonfinite) / count;
  m.ssim = ssim / ref.channels;
  return m;
}

void append_number(std::string& out, double v) {
  if (!std::isfinite(v)) {
    out += "null";
    return;
  }
  char buffer[32];
  std::snprintf(buffer, sizeof(buffer), "%.17g", v);
  out += buffer;
}

void append_metrics_json(std::string& out, const std::optional<ErrorMetrics>& m) {
  if (!m) {
    out += "null";
    return;
  }
  absl::StrAppend(&out, "{\"channels\":", m->channels, ",\"mse\":");
  append_number(out, m->mse);
  out += ",\"rel_mse\":";
  append_number(out, m->rel_mse);
  out += ",\"ssim\":";
  append_number(out, m->ssim);
  out += ",\"nonfinite_fraction\":";
  append_number(out, m->nonfinite_fraction);
  out += "}";
}

std::string metrics_line(const char* label, const std::optional<ErrorMetrics>& m) {
  if (!m) return absl::StrCat(label, "not compared\n");
  char buffer[256];
  std::snprintf(buffer, sizeof(buffer),
                "MSE %.6g  relMSE %.6g  SSIM %.6f  non-finite %.6g  (%d channels)\n", m->mse,
                m->rel_mse, m->ssim, m->nonfinite_fraction, m->channels);
  return absl::StrCat(label, buffer);
}

}  // namespace

absl::StatusOr<TileRect> crop_rect(const Crop& crop, int width, int height) {
  if (crop.w < 1 || crop.h < 1 || crop.x < 0 || crop.y < 0 ||
      std::int64_t{crop.x} + crop.w > width || std::int64_t{crop.y} + crop.h > height) {
    return absl::InvalidArgumentError(
        absl::StrCat("crop x=", crop.x, " y=", crop.y, " w=", crop.w, " h=", crop.h,
                     " must have w, h >= 1 and lie inside the ", width, "x", height, " image"));
  }
  return TileRect{crop.x, crop.y, crop.x + crop.w, crop.y + crop.h};
}

absl::StatusOr<ErrorMetrics> compare_spectral(const SpectralImage& test,
                                              const SpectralImage& reference,
                                              const std::optional<Crop>& crop) {
  return compare_views({test.data(), test.width(), test.height(), test.bins()},
                       {reference.data(), reference.width(), reference.height(), reference.bins()},
                       crop);
}

absl::StatusOr<ErrorMetrics> compare_rgb(const RgbImage& test, const RgbImage& reference,
                                         const std::optional<Crop>& crop) {
  return compare_views({test.data(), test.width(), test.height(), 3},
                       {reference.data(), reference.width(), reference.height(), 3}, crop);
}

absl::StatusOr<Comparison> compare_exr_files(const std::filesystem::path& test,
                                             const std::filesystem::path& reference,
                                             const std::optional<Crop>& crop) {
  PRISM_ASSIGN_OR_RETURN(ExrImage t, read_exr(test));
  PRISM_ASSIGN_OR_RETURN(ExrImage r, read_exr(reference));
  auto size_of = [](const ExrImage& image) {
    return image.spectral ? std::pair{image.spectral->width(), image.spectral->height()}
                          : std::pair{image.rgb->width(), image.rgb->height()};
  };
  auto [tw, th] = size_of(t);
  auto [rw, rh] = size_of(r);
  std::string names = absl::StrCat("test ", test.string(), " and reference ", reference.string());
  // A gradient render's raw gradient file holds differences of bins, not an image.
  for (const auto& [file, image] : {std::pair{&test, &t}, std::pair{&reference, &r}}) {
    if (auto content = image->metadata.find(std::string(kMetaContent));
        content != image->metadata.end() && content->second == "gradient") {
      return absl::InvalidArgumentError(
          absl::StrCat("cannot compare ", names, ": ", file->string(),
                       " holds the gradient of a gradient render (prism:content), not an image"));
    }
  }
  if (tw != rw || th != rh) {
    return absl::InvalidArgumentError(absl::StrCat("cannot compare ", names, ": sizes ", tw, "x",
                                                   th, " and ", rw, "x", rh, " differ"));
  }
  Comparison out;
  out.width = rw;
  out.height = rh;
  out.region = {0, 0, rw, rh};
  if (crop) {
    PRISM_ASSIGN_OR_RETURN(out.region, crop_rect(*crop, rw, rh));
  }
  if (t.spectral && r.spectral) {
    if (t.spectral->bins() != r.spectral->bins()) {
      return absl::InvalidArgumentError(absl::StrCat("cannot compare ", names, ": ",
                                                     t.spectral->bins(), " and ",
                                                     r.spectral->bins(), " spectral bins"));
    }
    if (t.wavelengths_nm != r.wavelengths_nm) {
      return absl::InvalidArgumentError(
          absl::StrCat("cannot compare ", names, ": their bin wavelengths differ"));
    }
    PRISM_ASSIGN_OR_RETURN(out.spectral, compare_spectral(*t.spectral, *r.spectral, crop));
  }
  if (t.rgb && r.rgb) {
    PRISM_ASSIGN_OR_RETURN(out.rgb, compare_rgb(*t.rgb, *r.rgb, crop));
  }
  if (!out.spectral && !out.rgb) {
    return absl::InvalidArgumentError(
        absl::StrCat("cannot compare ", names,
                     ": one is spectral without R, G, B and the other is not spectral"));
  }
  return out;
}

std::string format_comparison_text(const Comparison& comparison) {
  const TileRect& r = comparison.region;
  std::string out =
      absl::StrCat("region    x=", r.x0, " y=", r.y0, " w=", r.width(), " h=", r.height(), " of ",
                   comparison.width, "x", comparison.height, "\n");
  out += metrics_line("spectral  ", comparison.spectral);
  out += metrics_line("rgb       ", comparison.rgb);
  return out;
}

std::string format_comparison_json(const Comparison& comparison) {
  const TileRect& r = comparison.region;
  std::string out = absl::StrCat("{\"width\":", comparison.width, ",\"height\":", comparison.height,
                                 ",\"region\":{\"x0\":", r.x0, ",\"y0\":", r.y0, ",\"x1\":", r.x1,
                                 ",\"y1\":", r.y1, "},\"spectral\":");
  append_metrics_json(out, comparison.spectral);
  out += ",\"rgb\":";
  append_metrics_json(out, comparison.rgb);
  out += "}";
  return out;
}

}  // namespace prism::image
