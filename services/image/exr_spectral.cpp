#include "services/image/exr_spectral.h"

#include <ImfChannelList.h>
#include <ImfFrameBuffer.h>
#include <ImfHeader.h>
#include <ImfInputFile.h>
#include <ImfOutputFile.h>
#include <ImfStringAttribute.h>
#include <ImfThreading.h>
#include <half.h>
#include <unistd.h>

#include <algorithm>
#include <charconv>
#include <cmath>
#include <exception>
#include <fstream>
#include <functional>
#include <mutex>
#include <optional>
#include <set>
#include <stdexcept>

#include "absl/strings/str_cat.h"
#include "services/base/atomic_file.h"
#include "services/base/check.h"
#include "services/base/status.h"

namespace prism::image {
namespace {

bool starts_with(std::string_view s, std::string_view prefix) {
  return s.starts_with(prefix);
}
bool ends_with(std::string_view s, std::string_view suffix) {
  return s.ends_with(suffix);
}

constexpr const char* kLayoutVersionAttribute = "spectralLayoutVersion";
constexpr const char* kEmissiveUnitsAttribute = "emissiveUnits";

absl::Status validate_metadata(const std::filesystem::path& path, const ExrMetadata& metadata) {
  for (const auto& [key, value] : metadata) {
    bool clean = std::none_of(key.begin(), key.end(),
                              [](char c) { return static_cast<unsigned char>(c) < 0x20; });
    if (key.empty() || !clean) {
      return absl::InvalidArgumentError(absl::StrCat("cannot write ", path.string(),
                                                     ": metadata key \"", key,
                                                     "\" must be non-empty printable text"));
    }
  }
  return absl::OkStatus();
}

void insert_metadata(Imf::Header& header, const ExrMetadata& metadata) {
  for (const auto& [key, value] : metadata) {
    header.insert(std::string(kMetadataPrefix) + key, Imf::StringAttribute(value));
  }
}

ExrMetadata extract_metadata(const Imf::Header& header) {
  ExrMetadata metadata;
  for (auto it = header.begin(); it != header.end(); ++it) {
    std::string_view name = it.name();
    if (!starts_with(name, kMetadataPrefix)) continue;
    if (const auto* s = dynamic_cast<const Imf::StringAttribute*>(&it.attribute())) {
      metadata.emplace(std::string(name.substr(kMetadataPrefix.size())), s->value());
    }
  }
  return metadata;
}

// One channel of a band of rows to write: `base` points at the band's first value (pixel (0, y0)),
// pixels are `stride` values of `type` apart and rows `stride * width` values. The file stores
// the channel in the same type.
struct Plane {
  std::string name;
  const void* base;
  int stride;
  Imf::PixelType type;
};

// The planes of rows [y0, y0 + rows); the same channels, in the same order, for every band.
using PlaneSource = std::function<absl::StatusOr<std::vector<Plane>>(int y0, int rows)>;

// Writes the image in bands of `band_rows` rows (the last may be shorter), asking `source` for
// each band in turn, so a caller can stream an image that is never whole in memory.
// The pool only grows: writers running at once never shrink each other's.
void grow_global_exr_pool(int threads) {
  static std::mutex mutex;
  std::lock_guard<std::mutex> lock(mutex);
  if (Imf::globalThreadCount() < threads) Imf::setGlobalThreadCount(threads);
}

Imf::Compression to_imf(ExrCompression compression) {
  switch (compression) {
    case ExrCompression::kNone:
      return Imf::NO_COMPRESSION;
    case ExrCompression::kRle:
      return Imf::RLE_COMPRESSION;
    case ExrCompression::kZips:
      return Imf::ZIPS_COMPRESSION;
    case ExrCompression::kZip:
      return Imf::ZIP_COMPRESSION;
    case ExrCompression::kPiz:
      return Imf::PIZ_COMPRESSION;
  }
  PRISM_CHECK(false);
  return Imf::ZIP_COMPRESSION;
}

// A file's header: its size, compression, attributes (`decorate`) and the planes' channels.
Imf::Header exr_header(int width, int height, const ExrWriteOptions& options,
                       const std::vector<Plane>& planes,
                       const std::function<void(Imf::Header&)>& decorate) {
  Imf::Header header(width, height);
  header.compression() = to_imf(options.compression);
  decorate(header);
  for (const Plane& plane : planes) header.channels().insert(plane.name, Imf::Channel(plane.type));
  return header;
}

// The numThreads of an OutputFile or InputFile for these options. OpenEXR 3.1 sizes a file's
// line buffers by numThreads but runs the compression tasks on its global pool (0 threads: in
// place on the caller's thread), which this grows to fit.
int exr_file_threads(const ExrWriteOptions& options) {
  const int threads = std::clamp(options.threads, 1, 256);
  if (threads > 1) grow_global_exr_pool(threads);
  return threads > 1 ? threads : 0;
}

// Writes rows [y0, y0 + rows) from `planes` (their bases at pixel (0, y0)).
void write_band(Imf::OutputFile& file, int width, int y0, int rows,
                const std::vector<Plane>& planes) {
  const Imath::Box2i band({0, y0}, {width - 1, y0 + rows - 1});
  Imf::FrameBuffer frame;
  for (const Plane& plane : planes) {
    std::size_t size = plane.type == Imf::HALF ? sizeof(Imath::half) : sizeof(float);
    frame.insert(plane.name, Imf::Slice::Make(plane.type, plane.base, band, size * plane.stride,
                                              size * std::size_t(plane.stride) * width));
  }
  file.setFrameBuffer(frame);
  file.writePixels(rows);
}

absl::Status write_exr(const std::filesystem::path& path, int width, int height, int band_rows,
                       const PlaneSource& source, const std::function<void(Imf::Header&)>& decorate,
                       const ExrWriteOptions& options) {
  PRISM_CHECK(band_rows >= 1);
  return base::write_via_temp(path, [&](const std::filesystem::path& temp) -> absl::Status {
    try {
      std::optional<Imf::OutputFile> file;
      for (int y0 = 0; y0 < height; y0 += band_rows) {
        const int rows = std::min(band_rows, height - y0);
        PRISM_ASSIGN_OR_RETURN(std::vector<Plane> planes, source(y0, rows));
        if (!file.has_value()) {
          file.emplace(temp.c_str(), exr_header(width, height, options, planes, decorate),
                       exr_file_threads(options));
        }
        write_band(*file, width, y0, rows, planes);
      }
    } catch (const std::exception& e) {
      return absl::InternalError(absl::StrCat("cannot write EXR ", path.string(), ": ", e.what()));
    }
    return absl::OkStatus();
  });
}

// Planes over a whole image held in memory: one band.
PlaneSource whole(std::vector<Plane> planes) {
  return [planes = std::move(planes)](int, int) -> absl::StatusOr<std::vector<Plane>> {
    return planes;
  };
}

template <typename T>
std::vector<Plane> rgb_planes(const T* data, Imf::PixelType type) {
  return {{"R", data + 0, 3, type}, {"G", data + 1, 3, type}, {"B", data + 2, 3, type}};
}

// A spectral file's planes for a band: the bins, pixel-interleaved from `bins`, then R, G, B.
std::vector<Plane> spectral_planes(const std::vector<std::string>& names, const float* bins,
                                   const float* rgb) {
  const int count = static_cast<int>(names.size());
  std::vector<Plane> planes;
  planes.reserve(names.size() + 3);
  for (int b = 0; b < count; ++b) planes.push_back({names[b], bins + b, count, Imf::FLOAT});
  for (Plane& plane : rgb_planes(rgb, Imf::FLOAT)) planes.push_back(std::move(plane));
  return planes;
}

enum class ReadMode {
  kSpectral,  // spectral channels required, RGB read when present
  kRgb,       // R, G, B required, spectral channels ignored
  kAny,       // both read when present, at least one required
};

absl::Status check_size(const std::filesystem::path& path, std::int64_t width, std::int64_t height,
                        std::size_t channels) {
  if (width < 1 || height < 1 || width > kMaxImageSide || height > kMaxImageSide ||
      std::uint64_t(width) * std::uint64_t(height) * std::max<std::size_t>(channels, 1) >
          kMaxImageValues) {
    return absl::InvalidArgumentError(
        absl::StrCat(path.string(), ": data window of ", width, "x", height, " with ", channels,
                     " channels is outside the supported size (sides 1..", kMaxImageSide,
                     ", at most ", kMaxImageValues, " values)"));
  }
  return absl::OkStatus();
}

absl::StatusOr<ExrImage> read_exr_channels(const std::filesystem::path& path, ReadMode mode) {
  bool want_spectral = mode != ReadMode::kRgb;
  std::error_code ec;
  if (!std::filesystem::exists(path, ec)) {
    return absl::NotFoundError(absl::StrCat("EXR file not found: ", path.string()));
  }
  try {
    Imf::InputFile file(path.c_str());
    const Imf::Header& header = file.header();
    Imath::Box2i window = header.dataWindow();
    std::int64_t width = std::int64_t(window.max.x) - window.min.x + 1;
    std::int64_t height = std::int64_t(window.max.y) - window.min.y + 1;

    std::vector<std::pair<double, std::string>> spectral_channels;
    std::set<std::string> names;
    for (auto it = header.channels().begin(); it != header.channels().end(); ++it) {
      std::string name = it.name();
      names.insert(name);
      bool polarised =
          starts_with(name, "S1.") || starts_with(name, "S2.") || starts_with(name, "S3.");
      if (want_spectral && polarised) {
        return absl::InvalidArgumentError(
            absl::StrCat(path.string(), ": channel ", name,
                         " belongs to the polarised spectral layout (Stokes S1..S3), which Prism "
                         "does not read"));
      }
      if (want_spectral && starts_with(name, "T.")) {
        return absl::InvalidArgumentError(absl::StrCat(
            path.string(), ": channel ", name,
            " belongs to the reflective spectral layout (T.*), which Prism does not read"));
      }
      bool wanted = want_spectral && starts_with(name, "S0.");
      bool rgb = name == "R" || name == "G" || name == "B";
      if ((wanted || rgb) && (it.channel().xSampling != 1 || it.channel().ySampling != 1)) {
        return absl::InvalidArgumentError(absl::StrCat(path.string(), ": channel ", name,
                                                       " is subsampled, which is not supported"));
      }
      if (!wanted) continue;
      std::optional<double> lambda = parse_spectral_channel_name(name);
      if (!lambda) {
        return absl::InvalidArgumentError(absl::StrCat(
            path.string(), ": spectral channel ", name,
            " is not of the form S0.<wavelength>nm (e.g. S0.550,5nm); other units are not read"));
      }
      spectral_channels.emplace_back(*lambda, name);
    }
    bool has_rgb = names.count("R") && names.count("G") && names.count("B");

    ExrImage out;
    out.metadata = extract_metadata(header);
    if (spectral_channels.empty() && mode == ReadMode::kAny && !has_rgb) {
      return absl::InvalidArgumentError(absl::StrCat(
          path.string(), " has neither spectral channels (S0.<wavelength>nm) nor R, G, B"));
    }
    if (want_spectral) {
      if (spectral_channels.empty() && mode == ReadMode::kSpectral) {
        return absl::InvalidArgumentError(
            absl::StrCat(path.string(), " has no spectral channels (S0.<wavelength>nm)",
                         has_rgb ? "; it is a plain RGB EXR, read it as RGB instead" : ""));
      }
      if (const auto* version =
              header.findTypedAttribute<Imf::StringAttribute>(kLayoutVersionAttribute);
          version && !starts_with(version->value(), "1.")) {
        return absl::InvalidArgumentError(absl::StrCat(path.string(),
                                                       " uses spectral layout version ",
                                                       version->value(), "; Prism reads 1.x"));
      }
      std::sort(spectral_channels.begin(), spectral_channels.end());
      for (std::size_t i = 1; i < spectral_channels.size(); ++i) {
        if (spectral_channels[i].first == spectral_channels[i - 1].first) {
          return absl::InvalidArgumentError(
              absl::StrCat(path.string(), ": channels ", spectral_channels[i - 1].second, " and ",
                           spectral_channels[i].second, " name the same wavelength"));
        }
      }
      if (spectral_channels.size() > std::size_t(kMaxChannels)) {
        return absl::InvalidArgumentError(
            absl::StrCat(path.string(), " has ", spectral_channels.size(),
                         " spectral channels; at most ", kMaxChannels, " are supported"));
      }
    } else if (!has_rgb) {
      return absl::InvalidArgumentError(
          absl::StrCat(path.string(), " lacks one of the channels R, G, B"));
    }
    std::size_t total_channels = spectral_channels.size() + (has_rgb ? 3 : 0);
    PRISM_RETURN_IF_ERROR(check_size(path, width, height, total_channels));

    Imf::FrameBuffer frame;
    int bins = static_cast<int>(spectral_channels.size());
    std::vector<float> spectral_data(std::size_t(width) * height * bins);
    std::vector<float> rgb_data(has_rgb ? std::size_t(width) * height * 3 : 0);
    for (int b = 0; b < bins; ++b) {
      frame.insert(
          spectral_channels[b].second,
          Imf::Slice::Make(Imf::FLOAT, spectral_data.data() + b, window, sizeof(float) * bins,
                           sizeof(float) * std::size_t(bins) * width));
    }
    if (has_rgb) {
      const char* rgb_names[3] = {"R", "G", "B"};
      for (int c = 0; c < 3; ++c) {
        frame.insert(rgb_names[c], Imf::Slice::Make(Imf::FLOAT, rgb_data.data() + c, window,
                                                    sizeof(float) * 3, sizeof(float) * 3 * width));
      }
    }
    file.setFrameBuffer(frame);
    file.readPixels(window.min.y, window.max.y);

    for (const auto& channel : spectral_channels) out.wavelengths_nm.push_back(channel.first);
    if (bins > 0) {
      PRISM_ASSIGN_OR_RETURN(
          SpectralImage spectral,
          SpectralImage::from_data(int(width), int(height), bins, std::move(spectral_data)));
      out.spectral = std::move(spectral);
    }
    if (has_rgb) {
      PRISM_ASSIGN_OR_RETURN(RgbImage rgb,
                             RgbImage::from_data(int(width), int(height), std::move(rgb_data)));
      out.rgb = std::move(rgb);
    }
    return out;
  } catch (const std::exception& e) {
    // A file of another kind: say which, rather than OpenEXR's "not an image file".
    std::string magic(8, '\0');
    if (std::ifstream in(path, std::ios::binary); in.read(magic.data(), 8) || in.gcount() > 0) {
      if (magic.starts_with("\x89PNG")) {
        return absl::InvalidArgumentError(
            absl::StrCat("cannot read ", path.string(),
                         ": it is a PNG, and an OpenEXR file is wanted (a "
                         "render's .exr or .rgb.exr)"));
      }
    }
    return absl::InvalidArgumentError(
        absl::StrCat("cannot read EXR ", path.string(), ": ", e.what()));
  }
}

}  // namespace

double bin_centre_nm(int b, int bins) {
  PRISM_CHECK(bins >= 1 && b >= 0 && b < bins);
  // One rounding: (360*2B + (2b+1)*470) / (2B) with an exact integer numerator.
  double numerator = kLambdaMinNm * 2.0 * bins + (2.0 * b + 1.0) * (kLambdaMaxNm - kLambdaMinNm);
  return numerator / (2.0 * bins);
}

std::vector<double> bin_centres_nm(int bins) {
  std::vector<double> centres(bins);
  for (int b = 0; b < bins; ++b) centres[b] = bin_centre_nm(b, bins);
  return centres;
}

std::string spectral_channel_name(double wavelength_nm) {
  PRISM_CHECK(std::isfinite(wavelength_nm) && wavelength_nm > 0.0);
  char buffer[512];
  auto [end, ec] =
      std::to_chars(buffer, buffer + sizeof(buffer), wavelength_nm, std::chars_format::fixed);
  PRISM_CHECK(ec == std::errc());
  std::string number(buffer, end);
  std::replace(number.begin(), number.end(), '.', ',');
  return absl::StrCat("S0.", number, "nm");
}

std::optional<double> parse_spectral_channel_name(std::string_view name) {
  if (!starts_with(name, "S0.") || !ends_with(name, "nm")) return std::nullopt;
  std::string number(name.substr(3, name.size() - 5));
  if (number.empty()) return std::nullopt;
  int separators = 0;
  int digits = 0;
  for (char& c : number) {
    if (c == ',' || c == '.') {
      c = '.';
      ++separators;
    } else if (c >= '0' && c <= '9') {
      ++digits;
    } else {
      return std::nullopt;
    }
  }
  if (separators > 1 || digits == 0) return std::nullopt;
  double value = 0.0;
  auto [ptr, ec] = std::from_chars(number.data(), number.data() + number.size(), value,
                                   std::chars_format::fixed);
  if (ec != std::errc() || ptr != number.data() + number.size()) return std::nullopt;
  if (!std::isfinite(value) || value <= 0.0) return std::nullopt;
  return value;
}

std::string_view name(ExrCompression compression) {
  switch (compression) {
    case ExrCompression::kNone:
      return "none";
    case ExrCompression::kRle:
      return "rle";
    case ExrCompression::kZips:
      return "zips";
    case ExrCompression::kZip:
      return "zip";
    case ExrCompression::kPiz:
      return "piz";
  }
  PRISM_CHECK(false);
  return "";
}

std::vector<ExrCompression> all_exr_compressions() {
  return {ExrCompression::kNone, ExrCompression::kRle, ExrCompression::kZips, ExrCompression::kZip,
          ExrCompression::kPiz};
}

std::optional<ExrCompression> parse_exr_compression(std::string_view text) {
  for (ExrCompression c : all_exr_compressions()) {
    if (name(c) == text) return c;
  }
  return std::nullopt;
}

absl::Status write_spectral_exr(const std::filesystem::path& path, const SpectralImage& spectral,
                                const RgbImage& rgb, const ExrMetadata& metadata,
                                const ExrWriteOptions& options) {
  return write_spectral_exr(path, bin_centres_nm(spectral.bins()), spectral, rgb, metadata,
                            options);
}

absl::Status write_spectral_exr(const std::filesystem::path& path,
                                const std::vector<double>& wavelengths_nm,
                                const SpectralImage& spectral, const RgbImage& rgb,
                                const ExrMetadata& metadata, const ExrWriteOptions& options) {
  if (wavelengths_nm.size() != std::size_t(spectral.bins())) {
    return absl::InvalidArgumentError(absl::StrCat("cannot write ", path.string(), ": ",
                                                   wavelengths_nm.size(), " wavelengths for ",
                                                   spectral.bins(), " bins"));
  }
  const float* data = spectral.data().data();
  const std::size_t row_values = std::size_t(spectral.width()) * std::size_t(spectral.bins());
  return write_spectral_exr_rows(
      path, wavelengths_nm, spectral.width(), spectral.height(), spectral.height(),
      [&](int y0, int) -> absl::StatusOr<const float*> { return data + y0 * row_values; }, rgb,
      metadata, options);
}

namespace {

// The channel names of the bins; INVALID_ARGUMENT naming `path` unless the wavelengths are
// finite, positive, strictly ascending and distinct once formatted.
absl::StatusOr<std::vector<std::string>> spectral_channel_names(
    const std::filesystem::path& path, const std::vector<double>& wavelengths_nm) {
  if (wavelengths_nm.empty() || wavelengths_nm.size() > std::size_t(kMaxChannels)) {
    return absl::InvalidArgumentError(
        absl::StrCat("cannot write ", path.string(), ": ", wavelengths_nm.size(), " wavelengths"));
  }
  std::vector<std::string> names;
  std::set<std::string> seen;
  for (std::size_t b = 0; b < wavelengths_nm.size(); ++b) {
    double lambda = wavelengths_nm[b];
    if (!std::isfinite(lambda) || lambda <= 0.0 || (b > 0 && lambda <= wavelengths_nm[b - 1])) {
      return absl::InvalidArgumentError(
          absl::StrCat("cannot write ", path.string(),
                       ": wavelengths must be finite, positive and strictly "
                       "ascending; entry ",
                       b, " is ", lambda));
    }
    std::string name = spectral_channel_name(lambda);
    if (!seen.insert(name).second) {
      return absl::InvalidArgumentError(absl::StrCat("cannot write ", path.string(),
                                                     ": two wavelengths give the channel ", name));
    }
    names.push_back(std::move(name));
  }
  return names;
}

void decorate_spectral(Imf::Header& header, const ExrMetadata& metadata) {
  header.insert(kLayoutVersionAttribute, Imf::StringAttribute(std::string(kSpectralLayoutVersion)));
  header.insert(kEmissiveUnitsAttribute, Imf::StringAttribute(std::string(kEmissiveUnits)));
  insert_metadata(header, metadata);
}

}  // namespace

absl::Status write_spectral_exr_rows(const std::filesystem::path& path,
                                     const std::vector<double>& wavelengths_nm, int width,
                                     int height, int band_rows, const SpectralRows& rows,
                                     const RgbImage& rgb, const ExrMetadata& metadata,
                                     const ExrWriteOptions& options) {
  if (rgb.width() != width || rgb.height() != height) {
    return absl::InvalidArgumentError(
        absl::StrCat("cannot write ", path.string(), ": RGB image is ", rgb.width(), "x",
                     rgb.height(), " but the spectral image is ", width, "x", height));
  }
  if (band_rows < 1) {
    return absl::InvalidArgumentError(
        absl::StrCat("cannot write ", path.string(), ": ", band_rows, " rows per band"));
  }
  PRISM_ASSIGN_OR_RETURN(const std::vector<std::string> names,
                         spectral_channel_names(path, wavelengths_nm));
  PRISM_RETURN_IF_ERROR(validate_metadata(path, metadata));
  auto source = [&](int y0, int n) -> absl::StatusOr<std::vector<Plane>> {
    PRISM_ASSIGN_OR_RETURN(const float* band, rows(y0, n));
    return spectral_planes(names, band, rgb.data().data() + std::size_t(y0) * width * 3);
  };
  return write_exr(
      path, width, height, band_rows, source,
      [&](Imf::Header& header) { decorate_spectral(header, metadata); }, options);
}

namespace {

// The streamed file, written and read at explicit offsets of its descriptor (OpenEXR seeks back
// to fill in the line offsets). Errors surface as exceptions, as OpenEXR's own streams do.
class FdOStream final : public Imf::OStream {
 public:
  explicit FdOStream(int fd) : Imf::OStream("streamed spectral EXR"), fd_(fd) {}
  void write(const char c[], int n) override {
    const absl::Status s = base::pwrite_all(fd_, c, std::size_t(n), at_, "streamed spectral EXR");
    if (!s.ok()) throw std::runtime_error(std::string(s.message()));
    at_ += std::uint64_t(n);
    end_ = std::max(end_, at_);
  }
  std::uint64_t tellp() override { return at_; }
  void seekp(std::uint64_t pos) override { at_ = pos; }
  std::uint64_t end() const { return end_; }

 private:
  int fd_;
  std::uint64_t at_ = 0, end_ = 0;
};

class FdIStream final : public Imf::IStream {
 public:
  FdIStream(int fd, std::uint64_t size)
      : Imf::IStream("streamed spectral EXR"), fd_(fd), size_(size) {}
  bool read(char c[], int n) override {
    if (n < 0 || at_ + std::uint64_t(n) > size_) {
      throw std::runtime_error("read past the end of the streamed spectral EXR");
    }
    const absl::Status s = base::pread_all(fd_, c, std::size_t(n), at_, "streamed spectral EXR");
    if (!s.ok()) throw std::runtime_error(std::string(s.message()));
    at_ += std::uint64_t(n);
    return at_ < size_;
  }
  std::uint64_t tellg() override { return at_; }
  void seekg(std::uint64_t pos) override { at_ = pos; }

 private:
  int fd_;
  std::uint64_t size_, at_ = 0;
};

}  // namespace

struct SpectralExrStream::Open {
  FdOStream stream;
  std::optional<Imf::OutputFile> file;
  explicit Open(int fd) : stream(fd) {}
};

absl::StatusOr<std::unique_ptr<SpectralExrStream>> SpectralExrStream::create(
    const std::filesystem::path& dir, const std::vector<double>& wavelengths_nm, int width,
    int height, const ExrWriteOptions& options) {
  if (width < 1 || height < 1) {
    return absl::InvalidArgumentError(
        absl::StrCat("a streamed spectral EXR of ", width, "x", height, " pixels"));
  }
  PRISM_ASSIGN_OR_RETURN(std::vector<std::string> names,
                         spectral_channel_names(dir / "(streamed)", wavelengths_nm));
  PRISM_ASSIGN_OR_RETURN(const int fd, base::make_anonymous_file(dir, "a streamed spectral EXR"));
  std::unique_ptr<SpectralExrStream> stream(
      new SpectralExrStream(fd, width, height, exr_file_threads(options)));
  stream->names_ = std::move(names);
  try {
    stream->open_ = std::make_unique<Open>(fd);
    // The header write_exr makes for write_spectral_exr_rows, without the metadata.
    stream->open_->file.emplace(
        stream->open_->stream,
        exr_header(width, height, options, spectral_planes(stream->names_, nullptr, nullptr),
                   [](Imf::Header& header) { decorate_spectral(header, {}); }),
        stream->threads_);
  } catch (const std::exception& e) {
    return absl::InternalError(
        absl::StrCat("cannot start a streamed spectral EXR in ", dir.string(), ": ", e.what()));
  }
  return stream;
}

SpectralExrStream::SpectralExrStream(int fd, int width, int height, int threads)
    : fd_(fd), width_(width), height_(height), threads_(threads) {}

SpectralExrStream::~SpectralExrStream() {
  try {
    open_.reset();  // an unfinished file is abandoned with its descriptor
  } catch (...) {
  }
  ::close(fd_);
}

absl::Status SpectralExrStream::write_rows(int rows, const float* bins, const float* rgb) {
  if (open_ == nullptr || rows < 1 || rows > height_ - rows_written_) {
    return absl::InvalidArgumentError(absl::StrCat("a streamed spectral EXR of ", height_,
                                                   " rows has ", rows_written_,
                                                   " written; cannot take ", rows, " more"));
  }
  try {
    write_band(*open_->file, width_, rows_written_, rows, spectral_planes(names_, bins, rgb));
    rows_written_ += rows;
    if (rows_written_ == height_) {
      open_->file.reset();  // writes the line offsets
    }
  } catch (const std::exception& e) {
    open_.reset();
    return absl::InternalError(absl::StrCat("cannot write a streamed spectral EXR: ", e.what()));
  }
  return absl::OkStatus();
}

absl::Status SpectralExrStream::write(const std::filesystem::path& path,
                                      const ExrMetadata& metadata) {
  if (open_ == nullptr || rows_written_ != height_) {
    return absl::FailedPreconditionError(absl::StrCat("cannot write ", path.string(), ": ",
                                                      rows_written_, " of ", height_,
                                                      " rows were streamed"));
  }
  PRISM_RETURN_IF_ERROR(validate_metadata(path, metadata));
  const std::uint64_t size = open_->stream.end();
  return base::write_via_temp(path, [&](const std::filesystem::path& temp) -> absl::Status {
    try {
      FdIStream in_stream(fd_, size);
      Imf::InputFile in(in_stream, threads_ > 1 ? threads_ : 0);
      Imf::Header header = in.header();
      insert_metadata(header, metadata);
      Imf::OutputFile out(temp.c_str(), header, threads_ > 1 ? threads_ : 0);
      out.copyPixels(in);
    } catch (const std::exception& e) {
      return absl::InternalError(absl::StrCat("cannot write EXR ", path.string(), ": ", e.what()));
    }
    return absl::OkStatus();
  });
}

absl::StatusOr<SpectralExr> read_spectral_exr(const std::filesystem::path& path) {
  PRISM_ASSIGN_OR_RETURN(ExrImage contents, read_exr_channels(path, ReadMode::kSpectral));
  PRISM_CHECK(contents.spectral.has_value());
  return SpectralExr{std::move(contents.wavelengths_nm), std::move(*contents.spectral),
                     std::move(contents.rgb), std::move(contents.metadata)};
}

absl::StatusOr<ExrImage> read_exr(const std::filesystem::path& path) {
  return read_exr_channels(path, ReadMode::kAny);
}

absl::Status write_rgb_exr(const std::filesystem::path& path, const RgbImage& rgb,
                           ExrPixelType pixel_type, const ExrMetadata& metadata,
                           const ExrWriteOptions& options) {
  PRISM_RETURN_IF_ERROR(validate_metadata(path, metadata));
  auto decorate = [&](Imf::Header& header) { insert_metadata(header, metadata); };
  if (pixel_type == ExrPixelType::kFloat) {
    return write_exr(path, rgb.width(), rgb.height(), rgb.height(),
                     whole(rgb_planes(rgb.data().data(), Imf::FLOAT)), decorate, options);
  }
  // Imath's float -> half conversion rounds to nearest and overflows to infinity.
  std::vector<Imath::half> halves(rgb.data().begin(), rgb.data().end());
  return write_exr(path, rgb.width(), rgb.height(), rgb.height(),
                   whole(rgb_planes(halves.data(), Imf::HALF)), decorate, options);
}

absl::StatusOr<RgbExr> read_rgb_exr(const std::filesystem::path& path) {
  PRISM_ASSIGN_OR_RETURN(ExrImage contents, read_exr_channels(path, ReadMode::kRgb));
  PRISM_CHECK(contents.rgb.has_value());
  return RgbExr{std::move(*contents.rgb), std::move(contents.metadata)};
}

}  // namespace prism::image
