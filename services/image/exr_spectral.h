// Spectral and RGB OpenEXR files.
//
// Spectral files follow "An OpenEXR Layout for Spectral Images" (Fichet, Pacanowski, Wilkie,
// JCGT 10(3), 2021), emissive and unpolarised: one FLOAT32 channel per bin named
// `S0.<λ>nm`, where λ is the bin centre in nanometres written with a comma as the decimal
// separator and no trailing zeros (the shortest decimal that reads back as the same double:
// 363.671875 -> `S0.363,671875nm`, 365 -> `S0.365nm`); the header carries the string
// attributes spectralLayoutVersion = "1.0" and emissiveUnits = "W.m^-2.sr^-1". R, G, B
// FLOAT32 channels hold the caller's RGB rendering so ordinary viewers show the image. Prism's
// own metadata (spp, integrator, seed, job id, ...) are string attributes named
// `prism:<key>`. Pixel data are compressed losslessly (ExrCompression; RLE unless the caller
// chooses another), so values read back bit-exactly.
//
// Prism's grid: B bins over [360, 830] nm, bin b centred at 360 + (b + 0.5)*470/B nm.
//
// Readers accept what other renderers write (pbrt-v4's spectral film uses 3 decimals and may
// use a dot): every `S0.<λ>nm` channel with a comma or a dot (or no) decimal separator, sorted
// by λ. Any pixel type is converted to float; the data window (not the display window) is the
// image. Polarised (S1..S3) and reflective (T.*) layouts are refused, not misread.
// Every write is atomic: the file appears complete under its name or not at all.
#pragma once

#include <filesystem>
#include <functional>
#include <map>
#include <memory>
#include <optional>
#include <string>
#include <string_view>
#include <vector>

#include "absl/status/statusor.h"
#include "services/image/tile.h"

namespace prism::image {

inline constexpr double kLambdaMinNm = 360.0;
inline constexpr double kLambdaMaxNm = 830.0;
inline constexpr std::string_view kMetadataPrefix = "prism:";
inline constexpr std::string_view kSpectralLayoutVersion = "1.0";
inline constexpr std::string_view kEmissiveUnits = "W.m^-2.sr^-1";

// Well-known metadata keys (stored as prism:<key>); any other key is allowed too.
inline constexpr std::string_view kMetaSpp = "spp";
inline constexpr std::string_view kMetaIntegrator = "integrator";
inline constexpr std::string_view kMetaSeed = "seed";
inline constexpr std::string_view kMetaJobId = "job_id";

// Spectral gradient sampling (docs/estimators.md §5). A gradient file is a spectral EXR on Prism's
// grid whose `S0.<λ>nm` channel for bin b holds G[b], the estimate of I[b+k] − I[b] (bin indices
// cyclic mod B) for the primal I of the same render, with these keys:
//   gradient_offset_bins  k, the offset in bins, a decimal integer with 1 <= k < B;
//   gradient_delta        δ as a fraction of the range [360, 830] nm (informative: k decides).
// A reconstructed image (coordinator/poisson.h) records how it was made:
//   poisson_alpha         the screening weight α (shortest decimal that reads back exactly);
//   poisson_norm          "l2", "l1" or "weighted";
//   gradient_offset_bins  the k used.
// The raw pair of a gradient render (--primal-and-gradients) also says which is which:
//   content               "primal" or "gradient" (prism reconstruct checks it when present);
//                         "reconstruction" on a gradient job's image and reconstruct's output.
inline constexpr std::string_view kMetaContent = "content";
// On a gradient file of the raw pair: the SHA-256 of its primal's pixel values (the floats of the
// spectral image, row-major and pixel-interleaved, as written), which names the one primal it
// belongs with.
inline constexpr std::string_view kMetaPrimalSha256 = "primal_sha256";
inline constexpr std::string_view kMetaGradientOffsetBins = "gradient_offset_bins";
inline constexpr std::string_view kMetaGradientDelta = "gradient_delta";
inline constexpr std::string_view kMetaPoissonAlpha = "poisson_alpha";
inline constexpr std::string_view kMetaPoissonNorm = "poisson_norm";

// Keys without the prism: prefix -> values.
using ExrMetadata = std::map<std::string, std::string>;

// Centre of bin b of `bins` on Prism's grid, in nm, correctly rounded. 0 <= b < bins.
double bin_centre_nm(int b, int bins);
std::vector<double> bin_centres_nm(int bins);

// `S0.<λ>nm` for a wavelength in nm (finite, > 0), comma separator, no trailing zeros.
std::string spectral_channel_name(double wavelength_nm);
// The wavelength of an `S0.<λ>nm` channel name (comma or dot separator); nullopt when the
// name is not an emissive unpolarised spectral channel in nanometres.
std::optional<double> parse_spectral_channel_name(std::string_view name);

struct SpectralExr {
  std::vector<double> wavelengths_nm;  // ascending, one per bin of `spectral`
  SpectralImage spectral;
  std::optional<RgbImage> rgb;  // present when the file has R, G and B channels
  ExrMetadata metadata;
};

struct RgbExr {
  RgbImage rgb;
  ExrMetadata metadata;
};

// Whatever a file holds of the above: spectral channels and/or R, G, B.
struct ExrImage {
  std::vector<double> wavelengths_nm;  // empty when there are no spectral channels
  std::optional<SpectralImage> spectral;
  std::optional<RgbImage> rgb;
  ExrMetadata metadata;
};

// The lossless compressions OpenEXR offers for float data. Lossy ones (PXR24, B44, DWA) are not
// offered: a spectral reference must read back bit-exactly. Compression works on blocks of scan
// lines (1 for ZIPS and RLE, 16 for ZIP, 32 for PIZ) that OpenEXR's thread pool compresses in
// parallel; the bytes written do not depend on the thread count.
enum class ExrCompression { kNone, kRle, kZips, kZip, kPiz };
// RLE: on the renders measured in docs/benchmarks.md ("Output") it writes 4-6x faster than ZIP
// and within 3-23 % of ZIP's size (spectral images have runs of exact zeros where nothing emits).
inline constexpr ExrCompression kDefaultExrCompression = ExrCompression::kRle;

// "none", "rle", "zips", "zip", "piz".
std::string_view name(ExrCompression compression);
// The inverse of name(); nullopt for anything else.
std::optional<ExrCompression> parse_exr_compression(std::string_view text);
// All of them, in the enum's order (for help texts and benchmarks).
std::vector<ExrCompression> all_exr_compressions();

struct ExrWriteOptions {
  ExrCompression compression = kDefaultExrCompression;
  // Threads compressing line blocks (OpenEXR's thread pool); 1 compresses on the caller's
  // thread. Clamped to [1, 256].
  int threads = 1;
};

// Writes spectral + RGB on Prism's grid (wavelengths from bin_centres_nm(spectral.bins())).
// INVALID_ARGUMENT when rgb's size differs or a metadata key is empty or has control
// characters; INTERNAL (naming the file) when OpenEXR or the file system fails.
absl::Status write_spectral_exr(const std::filesystem::path& path, const SpectralImage& spectral,
                                const RgbImage& rgb, const ExrMetadata& metadata = {},
                                const ExrWriteOptions& options = {});
// Same with explicit wavelengths: strictly ascending, finite, > 0, one per bin, and distinct
// once formatted as channel names.
absl::Status write_spectral_exr(const std::filesystem::path& path,
                                const std::vector<double>& wavelengths_nm,
                                const SpectralImage& spectral, const RgbImage& rgb,
                                const ExrMetadata& metadata = {},
                                const ExrWriteOptions& options = {});

// Rows [y0, y0 + rows) of a spectral image, row-major and pixel-interleaved (width*rows*bins
// floats, as SpectralImage lays them out), valid until the next call.
using SpectralRows = std::function<absl::StatusOr<const float*>(int y0, int rows)>;

// The same file as write_spectral_exr, streamed: `rows` is asked for bands of `band_rows` rows
// from the top (the last band may be shorter), so the spectral image need never be whole in
// memory (the coordinator writes a job's output from its finished tiles this way). `rgb` is
// the whole image. An error from `rows` abandons the file (nothing appears under `path`).
absl::Status write_spectral_exr_rows(const std::filesystem::path& path,
                                     const std::vector<double>& wavelengths_nm, int width,
                                     int height, int band_rows, const SpectralRows& rows,
                                     const RgbImage& rgb, const ExrMetadata& metadata = {},
                                     const ExrWriteOptions& options = {});

// A spectral EXR written band by band while a render runs, so that compressing it overlaps the
// render instead of following it (issue 18). Its lines go, compressed, to an anonymous file in
// `dir`; write() then makes the file at `path` with metadata known only at the end, copying the
// compressed lines as they are (OpenEXR's copyPixels): the same bytes as write_spectral_exr_rows
// with the same rows, RGB and metadata. Not thread-safe: one writer at a time.
class SpectralExrStream {
 public:
  // INVALID_ARGUMENT for wavelengths write_spectral_exr_rows refuses; INTERNAL naming `dir` when
  // the anonymous file cannot be made.
  static absl::StatusOr<std::unique_ptr<SpectralExrStream>> create(
      const std::filesystem::path& dir, const std::vector<double>& wavelengths_nm, int width,
      int height, const ExrWriteOptions& options = {});
  ~SpectralExrStream();
  SpectralExrStream(const SpectralExrStream&) = delete;
  SpectralExrStream& operator=(const SpectralExrStream&) = delete;

  // The next `rows` rows from the top: `bins` pixel-interleaved (width·rows·bins floats),
  // `rgb` width·rows·3 floats. INVALID_ARGUMENT past the last row; INTERNAL on a write error.
  absl::Status write_rows(int rows, const float* bins, const float* rgb);
  int rows_written() const { return rows_written_; }

  // Makes the file at `path` (atomically, as every output) once every row is written;
  // FAILED_PRECONDITION before that, INVALID_ARGUMENT for bad metadata, INTERNAL naming the file
  // on an I/O error.
  absl::Status write(const std::filesystem::path& path, const ExrMetadata& metadata);

 private:
  struct Open;
  SpectralExrStream(int fd, int width, int height, int threads);

  int fd_;
  int width_, height_;
  int threads_;  // the OpenEXR files' numThreads
  int rows_written_ = 0;
  std::vector<std::string> names_;
  std::unique_ptr<Open> open_;  // the OpenEXR file being written, until the last row
};

// Reads a spectral EXR (see above). NOT_FOUND for a missing file; INVALID_ARGUMENT naming the
// file when it is not an EXR, has no S0.<λ>nm channels, uses the polarised or reflective
// layout, repeats a wavelength, has subsampled channels or is larger than kMaxImageValues.
absl::StatusOr<SpectralExr> read_spectral_exr(const std::filesystem::path& path);

// Reads spectral channels and RGB, whichever are present; same errors as read_spectral_exr
// except that a file with R, G, B and no spectral channels is accepted. INVALID_ARGUMENT when
// it has neither.
absl::StatusOr<ExrImage> read_exr(const std::filesystem::path& path);

enum class ExrPixelType {
  kHalf,   // 16-bit float: ~3 significant digits, largest finite value 65504 (larger -> inf)
  kFloat,  // 32-bit float: exact
};

// Writes R, G, B channels (compressed as `options` say) plus prism:<key> metadata; atomic.
absl::Status write_rgb_exr(const std::filesystem::path& path, const RgbImage& rgb,
                           ExrPixelType pixel_type = ExrPixelType::kFloat,
                           const ExrMetadata& metadata = {}, const ExrWriteOptions& options = {});

// Reads the R, G, B channels of any EXR (plain RGB or spectral with RGB), converted to float.
// INVALID_ARGUMENT naming the file when one of them is missing.
absl::StatusOr<RgbExr> read_rgb_exr(const std::filesystem::path& path);

}  // namespace prism::image
