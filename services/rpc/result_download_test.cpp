#include "services/rpc/result_download.h"

#include <gtest/gtest.h>

#include <deque>
#include <string>

#include "services/base/sha256.h"

namespace prism::rpc {
namespace {

namespace v1 = prism::v1;

// A GetResult stream that replays the given chunks.
class ReplayReader : public grpc::ClientReaderInterface<v1::ResultChunk> {
 public:
  explicit ReplayReader(std::deque<v1::ResultChunk> chunks) : chunks_(std::move(chunks)) {}
  bool Read(v1::ResultChunk* chunk) override {
    if (chunks_.empty()) return false;
    *chunk = std::move(chunks_.front());
    chunks_.pop_front();
    return true;
  }
  bool NextMessageSize(std::uint32_t* size) override {
    *size = chunks_.empty() ? 0 : std::uint32_t(chunks_.front().ByteSizeLong());
    return !chunks_.empty();
  }
  void WaitForInitialMetadata() override {}
  grpc::Status Finish() override { return grpc::Status::OK; }

 private:
  std::deque<v1::ResultChunk> chunks_;
};

// `bytes` as chunks of `size` bytes (the file's SHA-256 on the last, or `sha` when given).
std::deque<v1::ResultChunk> chunked(v1::OutputKind kind, const std::string& name,
                                    const std::string& bytes, std::size_t size,
                                    std::string sha = "") {
  std::deque<v1::ResultChunk> chunks;
  for (std::size_t at = 0; at == 0 || at < bytes.size(); at += size) {
    v1::ResultChunk c;
    c.set_kind(kind);
    c.set_file_name(name);
    c.set_offset(at);
    c.set_data(bytes.substr(at, size));
    c.set_last(at + size >= bytes.size());
    if (c.last()) c.set_sha256(sha.empty() ? base::sha256_hex(bytes) : sha);
    chunks.push_back(std::move(c));
  }
  return chunks;
}

TEST(ResultDownloadTest, InterleavedFilesAssembleToTheirBytes) {
  const std::string exr(2500, 'e'), json = "{\"spp\": 4}";
  std::deque<v1::ResultChunk> a = chunked(v1::OUTPUT_KIND_SPECTRAL_EXR, "r.exr", exr, 1000);
  std::deque<v1::ResultChunk> b = chunked(v1::OUTPUT_KIND_REPORT_JSON, "r.json", json, 4);
  std::deque<v1::ResultChunk> mixed;
  while (!a.empty() || !b.empty()) {
    for (auto* q : {&a, &b}) {
      if (q->empty()) continue;
      mixed.push_back(q->front());
      q->pop_front();
    }
  }
  ReplayReader reader(mixed);
  absl::StatusOr<ResultFiles> got = read_result_files(reader);
  ASSERT_TRUE(got.ok()) << got.status();
  EXPECT_FALSE(got->ended_inside_a_file);
  ASSERT_EQ(got->files.size(), 2u);
  EXPECT_EQ(got->files[v1::OUTPUT_KIND_SPECTRAL_EXR], exr);
  EXPECT_EQ(got->files[v1::OUTPUT_KIND_REPORT_JSON], json);
}

TEST(ResultDownloadTest, GapsWrongHashesAndCutStreamsAreCaught) {
  const std::string bytes(3000, 'x');
  std::deque<v1::ResultChunk> gap = chunked(v1::OUTPUT_KIND_PNG, "r.png", bytes, 1000);
  gap.erase(gap.begin() + 1);
  ReplayReader gap_reader(gap);
  absl::StatusOr<ResultFiles> got = read_result_files(gap_reader);
  ASSERT_TRUE(absl::IsDataLoss(got.status())) << got.status();
  EXPECT_NE(got.status().message().find("r.png: chunk at 2000, expected 1000"), std::string::npos)
      << got.status();

  ReplayReader wrong(chunked(v1::OUTPUT_KIND_PNG, "r.png", bytes, 1000, std::string(64, '0')));
  got = read_result_files(wrong);
  ASSERT_TRUE(absl::IsDataLoss(got.status())) << got.status();
  EXPECT_NE(got.status().message().find("r.png does not match"), std::string::npos);

  std::deque<v1::ResultChunk> cut = chunked(v1::OUTPUT_KIND_PNG, "r.png", bytes, 1000);
  cut.pop_back();
  ReplayReader cut_reader(cut);
  got = read_result_files(cut_reader);
  ASSERT_TRUE(got.ok()) << got.status();
  EXPECT_TRUE(got->ended_inside_a_file);
  EXPECT_TRUE(got->files.empty());
}

}  // namespace
}  // namespace prism::rpc
