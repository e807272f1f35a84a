#include "coordinator/rpc/farm_service.h"

#include <fstream>
#include <thread>

#include "absl/strings/str_cat.h"
#include "google/protobuf/util/message_differencer.h"
#include "services/base/sha256.h"
#include "services/rpc/auth.h"
#include "services/rpc/chunks.h"
#include "services/rpc/status_mapping.h"

namespace prism::coordinator::rpc {
namespace {

using prism::rpc::check_bearer;
using prism::rpc::to_grpc;

// A watch sends at most one update per this interval.
constexpr Millis kWatchInterval{200};

}  // namespace

absl::Status follow_job(FarmView& farm, const std::string& job_id,
                        const std::function<bool()>& stopped,
                        const std::function<bool(const prism::v1::JobInfo&)>& send) {
  std::optional<prism::v1::JobInfo> last;
  std::uint64_t seen = farm.change_counter();
  while (!stopped()) {
    absl::StatusOr<JobStatus> job = farm.job(job_id);
    if (!job.ok()) return job.status();
    prism::v1::JobInfo info = to_proto(*job);
    // Rates move continuously; an update is due when the state or the counts changed.
    prism::v1::JobInfo comparable = info;
    comparable.mutable_progress()->clear_samples_per_second();
    comparable.mutable_progress()->clear_eta_seconds();
    if (!last.has_value() ||
        !google::protobuf::util::MessageDifferencer::Equals(comparable, *last)) {
      if (!send(info)) return absl::OkStatus();  // the client went away
      last = std::move(comparable);
    }
    if (store::is_terminal(job->record.state)) return absl::OkStatus();
    std::this_thread::sleep_for(kWatchInterval);
    seen = farm.wait_for_change(seen, Millis(1000));
  }
  return absl::CancelledError("the watch was cancelled");
}

prism::v1::WorkerInfo to_proto(const WorkerStatus& w) {
  prism::v1::WorkerInfo info;
  info.set_worker_id(w.record.id);
  info.set_host(w.record.host);
  info.set_version(w.record.version);
  info.set_threads(static_cast<std::uint32_t>(w.record.threads));
  info.set_state(w.state);
  info.set_last_heartbeat_unix_ms(w.last_seen_ms);
  info.set_tasks_completed(w.tasks_completed);
  info.set_samples_completed(w.samples_completed);
  info.set_leases(static_cast<std::uint32_t>(w.leases));
  if (!w.current.empty()) {
    const Lease& lease = w.current.front();
    const TaskSpec& t = lease.task.spec;
    info.set_current_lease(lease.id);
    const std::string pass =
        t.pass == Pass::kFinal ? "final" : absl::StrCat("prepass ", t.pass_index);
    info.set_current_task(absl::StrCat("job ", lease.task.job_id, " ", pass, " tile (", t.tile.x0,
                                       ",", t.tile.y0, ")-(", t.tile.x1, ",", t.tile.y1,
                                       ") samples [", t.samples.s0, ",", t.samples.s1, ")"));
  }
  return info;
}

prism::v1::JobInfo to_proto(const JobStatus& status) {
  const store::JobRecord& r = status.record;
  prism::v1::JobInfo info;
  info.set_job_id(r.id);
  prism::v1::JobSpec spec;
  if (spec.ParseFromString(r.spec)) *info.mutable_spec() = std::move(spec);
  info.set_state(static_cast<prism::v1::JobState>(static_cast<int>(r.state)));
  auto* p = info.mutable_progress();
  p->set_tasks_total(r.progress.tasks_total);
  p->set_tasks_done(r.progress.tasks_done);
  p->set_samples_total(r.progress.samples_total);
  p->set_samples_done(r.progress.samples_done);
  p->set_samples_per_second(status.samples_per_second);
  p->set_eta_seconds(status.eta_seconds);
  p->set_tiles_finalised(static_cast<std::uint32_t>(status.tiles_finalised));
  p->set_tiles_total(static_cast<std::uint32_t>(status.tiles_total));
  info.set_error(r.error);
  info.set_submitted_unix_ms(r.submitted_ms);
  info.set_finished_unix_ms(r.finished_ms);
  info.set_report_json(r.report_json);
  info.set_waiting(status.waiting);
  return info;
}

FarmServiceImpl::FarmServiceImpl(FarmCoordinator& farm, std::string api_token,
                                 std::shared_ptr<spdlog::logger> logger)
    : farm_(farm), api_token_(std::move(api_token)), logger_(std::move(logger)) {}

grpc::Status FarmServiceImpl::refused(const grpc::ServerContext& context,
                                      const absl::Status& status) const {
  logger_->warn("refused a call from {}: {}", context.peer(), std::string(status.message()));
  return to_grpc(status);
}

grpc::Status FarmServiceImpl::SubmitJob(grpc::ServerContext* context,
                                        const prism::v1::SubmitJobRequest* request,
                                        prism::v1::SubmitJobResponse* response) {
  if (auto auth = check_bearer(*context, api_token_); !auth.ok()) return refused(*context, auth);
  absl::StatusOr<JobStatus> job = farm_.submit(request->spec(), request->client_token());
  if (!job.ok()) return to_grpc(job.status());
  *response->mutable_job() = to_proto(*job);
  return grpc::Status::OK;
}

grpc::Status FarmServiceImpl::GetJob(grpc::ServerContext* context,
                                     const prism::v1::GetJobRequest* request,
                                     prism::v1::JobInfo* response) {
  if (auto auth = check_bearer(*context, api_token_); !auth.ok()) return refused(*context, auth);
  absl::StatusOr<JobStatus> job = farm_.job(request->job_id());
  if (!job.ok()) return to_grpc(job.status());
  *response = to_proto(*job);
  return grpc::Status::OK;
}

grpc::Status FarmServiceImpl::ListJobs(grpc::ServerContext* context,
                                       const prism::v1::ListJobsRequest* request,
                                       prism::v1::ListJobsResponse* response) {
  if (auto auth = check_bearer(*context, api_token_); !auth.ok()) return refused(*context, auth);
  std::vector<store::JobState> states;
  for (int s : request->states()) {
    if (s < static_cast<int>(store::JobState::kQueued) ||
        s > static_cast<int>(store::JobState::kCancelled)) {
      return to_grpc(absl::InvalidArgumentError(absl::StrCat("states: unknown job state ", s)));
    }
    states.push_back(static_cast<store::JobState>(s));
  }
  absl::StatusOr<std::vector<JobStatus>> jobs = farm_.jobs(request->limit(), states);
  if (!jobs.ok()) return to_grpc(jobs.status());
  for (const JobStatus& job : *jobs) *response->add_jobs() = to_proto(job);
  return grpc::Status::OK;
}

grpc::Status FarmServiceImpl::WatchJob(grpc::ServerContext* context,
                                       const prism::v1::WatchJobRequest* request,
                                       grpc::ServerWriter<prism::v1::JobInfo>* writer) {
  if (auto auth = check_bearer(*context, api_token_); !auth.ok()) return refused(*context, auth);
  return to_grpc(follow_job(
      farm_, request->job_id(), [context] { return context->IsCancelled(); },
      [writer](const prism::v1::JobInfo& info) { return writer->Write(info); }));
}

grpc::Status FarmServiceImpl::CancelJob(grpc::ServerContext* context,
                                        const prism::v1::CancelJobRequest* request,
                                        prism::v1::JobInfo* response) {
  if (auto auth = check_bearer(*context, api_token_); !auth.ok()) return refused(*context, auth);
  absl::StatusOr<JobStatus> job = farm_.cancel(request->job_id());
  if (!job.ok()) return to_grpc(job.status());
  *response = to_proto(*job);
  return grpc::Status::OK;
}

grpc::Status FarmServiceImpl::GetResult(grpc::ServerContext* context,
                                        const prism::v1::GetResultRequest* request,
                                        grpc::ServerWriter<prism::v1::ResultChunk>* writer) {
  if (auto auth = check_bearer(*context, api_token_); !auth.ok()) return refused(*context, auth);
  std::vector<OutputKind> kinds;
  for (int k : request->kinds()) {
    if (k < static_cast<int>(OutputKind::kSpectralExr) ||
        k > static_cast<int>(OutputKind::kFilteredPng)) {
      return to_grpc(absl::InvalidArgumentError(
          absl::StrCat("kinds: output kind ", k, " is not produced by this coordinator")));
    }
    kinds.push_back(static_cast<OutputKind>(k));
  }
  absl::StatusOr<std::vector<OutputFile>> files = farm_.result_files(request->job_id(), kinds);
  if (!files.ok()) return to_grpc(files.status());
  std::string buffer(prism::rpc::kChunkBytes, '\0');
  for (const OutputFile& file : *files) {
    std::ifstream in(file.path, std::ios::binary);
    if (!in) {
      return to_grpc(absl::DataLossError(absl::StrCat("output ", file.file_name, " is missing")));
    }
    base::Sha256 hash;
    std::uint64_t offset = 0;
    // Read ahead one chunk so the last one can carry `last` and the hash.
    in.read(buffer.data(), static_cast<std::streamsize>(buffer.size()));
    std::string current(buffer.data(), static_cast<std::size_t>(in.gcount()));
    while (true) {
      std::string next;
      if (in) {
        in.read(buffer.data(), static_cast<std::streamsize>(buffer.size()));
        next.assign(buffer.data(), static_cast<std::size_t>(in.gcount()));
      }
      hash.update(current);
      prism::v1::ResultChunk chunk;
      chunk.set_kind(static_cast<prism::v1::OutputKind>(static_cast<int>(file.kind)));
      chunk.set_file_name(file.file_name);
      chunk.set_offset(offset);
      offset += current.size();
      const bool last = next.empty();
      chunk.set_data(std::move(current));
      if (last) {
        chunk.set_last(true);
        chunk.set_sha256(hash.hex());
      }
      if (!writer->Write(chunk)) return grpc::Status::OK;  // the client went away
      if (last) break;
      current = std::move(next);
    }
  }
  return grpc::Status::OK;
}

grpc::Status FarmServiceImpl::GetPreview(grpc::ServerContext* context,
                                         const prism::v1::GetPreviewRequest* request,
                                         prism::v1::Preview* response) {
  if (auto auth = check_bearer(*context, api_token_); !auth.ok()) return refused(*context, auth);
  absl::StatusOr<std::string> png = farm_.preview_png(request->job_id(), request->exposure());
  if (!png.ok()) return to_grpc(png.status());
  response->set_png(*std::move(png));
  return grpc::Status::OK;
}

grpc::Status FarmServiceImpl::ListWorkers(grpc::ServerContext* context,
                                          const prism::v1::ListWorkersRequest*,
                                          prism::v1::ListWorkersResponse* response) {
  if (auto auth = check_bearer(*context, api_token_); !auth.ok()) return refused(*context, auth);
  absl::StatusOr<std::vector<WorkerStatus>> workers = farm_.workers();
  if (!workers.ok()) return to_grpc(workers.status());
  for (const WorkerStatus& w : *workers) *response->add_workers() = to_proto(w);
  return grpc::Status::OK;
}

grpc::Status FarmServiceImpl::UploadBundle(grpc::ServerContext* context,
                                           grpc::ServerReader<prism::v1::BundleChunk>* reader,
                                           prism::v1::UploadBundleResponse* response) {
  if (auto auth = check_bearer(*context, api_token_); !auth.ok()) return refused(*context, auth);
  prism::rpc::ChunkAssembler assembler(farm_.options().max_bundle_bytes);
  // BundleChunk carries no transfer hash: the bundle's content hash, which unpack() checks
  // against every file, covers the bytes. The running hash only lets the assembler finish.
  base::Sha256 running;
  std::string claimed;
  prism::v1::BundleChunk chunk;
  bool first = true;
  while (reader->Read(&chunk)) {
    if (first) claimed = chunk.bundle_hash();
    first = false;
    absl::Status added = assembler.add(assembler.received(), chunk.data(), chunk.total_bytes());
    if (!added.ok()) return to_grpc(added);
    running.update(chunk.data());
  }
  if (first) return to_grpc(absl::InvalidArgumentError("the upload has no chunks"));
  absl::StatusOr<std::string> bytes = assembler.finish(running.hex());
  if (!bytes.ok()) return to_grpc(bytes.status());
  absl::StatusOr<std::string> hash = farm_.upload_bundle(claimed, *bytes);
  if (!hash.ok()) return to_grpc(hash.status());
  response->set_bundle_hash(*hash);
  return grpc::Status::OK;
}

grpc::Status FarmServiceImpl::HasBundle(grpc::ServerContext* context,
                                        const prism::v1::HasBundleRequest* request,
                                        prism::v1::HasBundleResponse* response) {
  if (auto auth = check_bearer(*context, api_token_); !auth.ok()) return refused(*context, auth);
  if (!base::is_sha256_hex(request->bundle_hash())) {
    return to_grpc(absl::InvalidArgumentError(absl::StrCat(
        "bundle_hash '", request->bundle_hash(), "': want 64 lower case hex digits (SHA-256)")));
  }
  response->set_present(farm_.has_bundle(request->bundle_hash()));
  return grpc::Status::OK;
}

}  // namespace prism::coordinator::rpc
