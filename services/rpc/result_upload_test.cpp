#include "services/rpc/result_upload.h"

#include <gtest/gtest.h>

#include <string>
#include <vector>

#include "services/base/sha256.h"

namespace prism::rpc {
namespace {

// A CompleteTask stream that keeps what is written (and can fail a write).
class RecordingWriter : public grpc::ClientWriterInterface<prism::v1::ResultUpload> {
 public:
  bool Write(const prism::v1::ResultUpload& message, grpc::WriteOptions) override {
    if (fail_at_ >= 0 && int(messages.size()) == fail_at_) return false;
    messages.push_back(message);
    return true;
  }
  bool WritesDone() override {
    writes_done = true;
    return true;
  }
  grpc::Status Finish() override { return grpc::Status::OK; }
  void fail_at(int index) { fail_at_ = index; }

  std::vector<prism::v1::ResultUpload> messages;
  bool writes_done = false;

 private:
  int fail_at_ = -1;
};

// The stream the coordinator's assembler expects: the lease on the first chunk, contiguous
// offsets with the declared total on each, the SHA-256 and statistics on the last, zero counters
// left out; the assembled bytes are the result's.
TEST(ResultUploadTest, ChunksAssembleToTheBytesWithTheLeaseFirstAndTheStatisticsLast) {
  std::string bytes(10000, '\0');
  for (std::size_t i = 0; i < bytes.size(); ++i) bytes[i] = char(i * 7 + 3);
  ResultUploadHeader header{"w1", "lease-9", 1.5, 1234, {{"shifts", 7}, {"failed", 0}}, ""};
  RecordingWriter writer;
  ASSERT_TRUE(upload_result(writer, header, bytes, 4096).ok());
  EXPECT_TRUE(writer.writes_done);
  ASSERT_EQ(writer.messages.size(), 3u);
  ChunkAssembler assembler(1 << 20);
  for (std::size_t i = 0; i < writer.messages.size(); ++i) {
    const prism::v1::ResultUpload& m = writer.messages[i];
    EXPECT_EQ(m.worker_id(), i == 0 ? "w1" : "");
    EXPECT_EQ(m.lease_id(), i == 0 ? "lease-9" : "");
    EXPECT_EQ(m.last(), i == 2);
    EXPECT_EQ(m.total_bytes(), bytes.size());
    ASSERT_TRUE(assembler.add(m.offset(), m.data(), m.total_bytes()).ok());
  }
  const prism::v1::ResultUpload& last = writer.messages.back();
  EXPECT_EQ(last.sha256(), base::sha256_hex(bytes));
  EXPECT_EQ(last.render_seconds(), 1.5);
  EXPECT_EQ(last.rays(), 1234u);
  EXPECT_EQ(last.counters().size(), 1u);
  EXPECT_EQ(last.counters().at("shifts"), 7u);
  auto assembled = assembler.finish(last.sha256());
  ASSERT_TRUE(assembled.ok()) << assembled.status();
  EXPECT_EQ(*assembled, bytes);
}

// An empty result is one chunk that is both first and last; a given SHA-256 is sent as is; a
// failed write ends the stream (WritesDone, Finish) without writing further chunks.
TEST(ResultUploadTest, EmptyResultsGivenHashesAndBrokenStreams) {
  RecordingWriter empty;
  ASSERT_TRUE(upload_result(empty, {"w", "l", 0, 0, {}, ""}, "").ok());
  ASSERT_EQ(empty.messages.size(), 1u);
  EXPECT_TRUE(empty.messages[0].last());
  EXPECT_EQ(empty.messages[0].lease_id(), "l");
  EXPECT_EQ(empty.messages[0].sha256(), base::sha256_hex(""));

  RecordingWriter given;
  ASSERT_TRUE(upload_result(given, {"w", "l", 0, 0, {}, "abc"}, "xyz").ok());
  EXPECT_EQ(given.messages.back().sha256(), "abc");

  RecordingWriter broken;
  broken.fail_at(1);
  EXPECT_TRUE(upload_result(broken, {"w", "l", 0, 0, {}, ""}, std::string(100, 'x'), 10).ok());
  EXPECT_EQ(broken.messages.size(), 1u);
  EXPECT_TRUE(broken.writes_done);
}

}  // namespace
}  // namespace prism::rpc
