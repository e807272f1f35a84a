#include "services/store/blob_store.h"

#include "absl/strings/str_cat.h"
#include "services/base/atomic_file.h"
#include "services/base/sha256.h"
#include "services/base/status.h"

namespace prism::store {
namespace {

absl::Status check_hash(std::string_view hash) {
  if (!base::is_sha256_hex(hash)) {
    return absl::InvalidArgumentError(absl::StrCat("malformed blob hash '",
                                                   std::string(hash.substr(0, 80)),
                                                   "': want 64 lowercase hex digits"));
  }
  return absl::OkStatus();
}

}  // namespace

absl::StatusOr<BlobStore> BlobStore::open(const std::filesystem::path& root) {
  std::error_code ec;
  std::filesystem::create_directories(root, ec);
  if (ec || !std::filesystem::is_directory(root)) {
    return absl::FailedPreconditionError(absl::StrCat(
        "cannot use ", root.string(), " as a blob store directory", ec ? ": " + ec.message() : ""));
  }
  return BlobStore(root);
}

std::filesystem::path BlobStore::path_of(std::string_view hash) const {
  return root_ / std::string(hash.substr(0, 2)) / std::string(hash);
}

absl::StatusOr<std::string> BlobStore::put(std::string_view bytes) const {
  std::string hash = base::sha256_hex(bytes);
  PRISM_RETURN_IF_ERROR(put_verified(hash, bytes));
  return hash;
}

absl::Status BlobStore::put_verified(std::string_view hash, std::string_view bytes) const {
  PRISM_RETURN_IF_ERROR(check_hash(hash));
  if (base::sha256_hex(bytes) != hash) {
    return absl::InvalidArgumentError(
        absl::StrCat("blob content does not match its hash ", std::string(hash)));
  }
  return put_hashed(hash, bytes);
}

absl::Status BlobStore::put_hashed(std::string_view hash, std::string_view bytes) const {
  PRISM_RETURN_IF_ERROR(check_hash(hash));
  if (contains(hash)) return absl::OkStatus();
  auto path = path_of(hash);
  std::error_code ec;
  std::filesystem::create_directories(path.parent_path(), ec);
  if (ec) {
    return absl::InternalError(
        absl::StrCat("cannot create ", path.parent_path().string(), ": ", ec.message()));
  }
  return base::write_file_atomic(path, bytes);
}

bool BlobStore::contains(std::string_view hash) const {
  if (!base::is_sha256_hex(hash)) return false;
  std::error_code ec;
  return std::filesystem::is_regular_file(path_of(hash), ec);
}

absl::Status BlobStore::remove(std::string_view hash) const {
  PRISM_RETURN_IF_ERROR(check_hash(hash));
  std::error_code ec;
  std::filesystem::remove(path_of(hash), ec);
  if (ec) {
    return absl::InternalError(
        absl::StrCat("cannot delete blob ", std::string(hash), ": ", ec.message()));
  }
  return absl::OkStatus();
}

absl::Status BlobStore::discard(std::string_view hash, const std::filesystem::path& dir) const {
  PRISM_RETURN_IF_ERROR(check_hash(hash));
  std::error_code ec;
  std::filesystem::rename(path_of(hash), dir / std::string(hash), ec);
  if (ec && ec != std::errc::no_such_file_or_directory) {
    return absl::InternalError(
        absl::StrCat("cannot discard blob ", std::string(hash), ": ", ec.message()));
  }
  return absl::OkStatus();
}

absl::StatusOr<std::string> BlobStore::get(std::string_view hash, std::uint64_t max_bytes) const {
  PRISM_RETURN_IF_ERROR(check_hash(hash));
  auto bytes = base::read_file(path_of(hash), max_bytes);
  if (absl::IsNotFound(bytes.status())) {
    return absl::NotFoundError(absl::StrCat("no blob ", std::string(hash)));
  }
  if (!bytes.ok()) return bytes.status();
  if (base::sha256_hex(*bytes) != hash) {
    return absl::DataLossError(absl::StrCat("blob ", std::string(hash), " is corrupt on disk"));
  }
  return bytes;
}

absl::StatusOr<std::uint64_t> BlobStore::size(std::string_view hash) const {
  PRISM_RETURN_IF_ERROR(check_hash(hash));
  std::error_code ec;
  auto bytes = std::filesystem::file_size(path_of(hash), ec);
  if (ec) return absl::NotFoundError(absl::StrCat("no blob ", std::string(hash)));
  return bytes;
}

}  // namespace prism::store
