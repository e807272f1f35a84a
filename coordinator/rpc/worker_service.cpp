#include "coordinator/rpc/worker_service.h"

#include <algorithm>

#include "absl/strings/str_cat.h"
#include "services/rpc/auth.h"
#include "services/rpc/chunks.h"
#include "services/rpc/status_mapping.h"

namespace prism::coordinator::rpc {
namespace {

using prism::rpc::check_bearer;
using prism::rpc::to_grpc;

prism::v1::TileRect to_proto(const image::TileRect& r) {
  prism::v1::TileRect out;
  out.set_x0(r.x0);
  out.set_y0(r.y0);
  out.set_x1(r.x1);
  out.set_y1(r.y1);
  return out;
}

absl::StatusOr<FailureClass> failure_class_of(prism::v1::FailureClass value) {
  switch (value) {
    case prism::v1::FAILURE_CLASS_SCENE:
      return FailureClass::kScene;
    case prism::v1::FAILURE_CLASS_WORKER:
      return FailureClass::kWorker;
    case prism::v1::FAILURE_CLASS_INFRASTRUCTURE:
      return FailureClass::kInfrastructure;
    case prism::v1::FAILURE_CLASS_RETURNED:
      return FailureClass::kReturned;
    default:
      break;
  }
  return absl::InvalidArgumentError(
      absl::StrCat("failure_class ", static_cast<int>(value),
                   ": want scene, worker, infrastructure or returned"));
}

}  // namespace

prism::v1::Lease to_proto(const LeaseGrant& grant) {
  prism::v1::Lease lease;
  lease.set_lease_id(grant.lease.id);
  lease.set_attempt(static_cast<std::uint32_t>(grant.lease.attempt));
  lease.set_deadline_unix_ms(grant.lease.deadline.count());
  lease.set_bundle_hash(grant.bundle_hash);
  prism::v1::Task* task = lease.mutable_task();
  task->set_job_id(grant.lease.task.job_id);
  const TaskSpec& spec = grant.lease.task.spec;
  task->set_pass(spec.pass == Pass::kPrepass ? prism::v1::PASS_PREPASS : prism::v1::PASS_FINAL);
  task->set_pass_index(static_cast<std::uint32_t>(spec.pass_index));
  *task->mutable_tile() = to_proto(spec.tile);
  task->mutable_samples()->set_begin(static_cast<std::uint32_t>(spec.samples.s0));
  task->mutable_samples()->set_end(static_cast<std::uint32_t>(spec.samples.s1));
  *task->mutable_spec() = grant.spec;
  if (grant.pdf_table.has_value()) {
    task->mutable_pdf_table()->set_cells(static_cast<std::uint32_t>(grant.table_cells));
    task->mutable_pdf_table()->set_quantised_cdf(*grant.pdf_table);
  }
  task->set_want_guides(grant.want_guides);
  task->set_early_stop_prepass(grant.early_stop);
  task->set_film_width(static_cast<std::uint32_t>(grant.film_width));
  task->set_film_height(static_cast<std::uint32_t>(grant.film_height));
  return lease;
}

WorkerServiceImpl::WorkerServiceImpl(FarmCoordinator& farm, std::string worker_secret,
                                     std::shared_ptr<spdlog::logger> logger)
    : farm_(farm), worker_secret_(std::move(worker_secret)), logger_(std::move(logger)) {}

grpc::Status WorkerServiceImpl::refused(const grpc::ServerContext& context,
                                        const absl::Status& status) const {
  logger_->warn("refused a call from {}: {}", context.peer(), std::string(status.message()));
  return to_grpc(status);
}

grpc::Status WorkerServiceImpl::Register(grpc::ServerContext* context,
                                         const prism::v1::RegisterRequest* request,
                                         prism::v1::RegisterResponse* response) {
  if (auto auth = check_bearer(*context, worker_secret_); !auth.ok())
    return refused(*context, auth);
  store::WorkerRecord record;
  record.host = request->host();
  record.version = request->version();
  record.threads = static_cast<int>(std::min<std::uint32_t>(request->threads(), 1u << 16));
  record.capabilities.assign(request->capabilities().begin(), request->capabilities().end());
  absl::StatusOr<store::WorkerRecord> stored =
      farm_.register_worker(std::move(record), request->previous_worker_id());
  if (!stored.ok()) return to_grpc(stored.status());
  response->set_worker_id(stored->id);
  response->set_heartbeat_interval_ms(
      static_cast<std::uint32_t>(farm_.options().scheduler.heartbeat_interval.count()));
  return grpc::Status::OK;
}

grpc::Status WorkerServiceImpl::AcquireTask(grpc::ServerContext* context,
                                            const prism::v1::AcquireTaskRequest* request,
                                            prism::v1::AcquireTaskResponse* response) {
  if (auto auth = check_bearer(*context, worker_secret_); !auth.ok())
    return refused(*context, auth);
  const Millis wait = std::min(Millis(request->wait_ms()), kMaxAcquireWait);
  absl::StatusOr<std::optional<LeaseGrant>> grant = farm_.acquire(request->worker_id(), wait);
  if (!grant.ok()) return to_grpc(grant.status());
  if (grant->has_value()) *response->mutable_lease() = to_proto(**grant);
  return grpc::Status::OK;
}

grpc::Status WorkerServiceImpl::Heartbeat(grpc::ServerContext* context,
                                          const prism::v1::HeartbeatRequest* request,
                                          prism::v1::HeartbeatResponse* response) {
  if (auto auth = check_bearer(*context, worker_secret_); !auth.ok())
    return refused(*context, auth);
  const std::vector<std::string> leases(request->lease_ids().begin(), request->lease_ids().end());
  const HeartbeatReply reply = farm_.heartbeat(request->worker_id(), leases);
  for (const Directive& d : reply.directives) {
    prism::v1::Directive* out = response->add_directives();
    switch (d.kind) {
      case DirectiveKind::kCancelTask:
        out->set_kind(prism::v1::Directive::KIND_CANCEL_TASK);
        break;
      case DirectiveKind::kDrain:
        out->set_kind(prism::v1::Directive::KIND_DRAIN);
        break;
      case DirectiveKind::kReregister:
        out->set_kind(prism::v1::Directive::KIND_REREGISTER);
        break;
    }
    out->set_lease_id(d.lease_id);
  }
  if (reply.lease_deadline.has_value()) {
    response->set_lease_deadline_unix_ms(reply.lease_deadline->count());
  }
  return grpc::Status::OK;
}

grpc::Status WorkerServiceImpl::CompleteTask(grpc::ServerContext* context,
                                             grpc::ServerReader<prism::v1::ResultUpload>* reader,
                                             prism::v1::CompleteTaskResponse* response) {
  if (auto auth = check_bearer(*context, worker_secret_); !auth.ok())
    return refused(*context, auth);
  prism::rpc::ChunkAssembler assembler(farm_.options().max_result_bytes);
  prism::v1::ResultUpload chunk;
  std::string worker_id, lease_id, sha256;
  double render_seconds = 0;
  std::uint64_t rays = 0;
  std::vector<std::pair<std::string, std::uint64_t>> counters;
  bool first = true, last = false;
  while (reader->Read(&chunk)) {
    if (last) return to_grpc(absl::InvalidArgumentError("a result chunk came after the last one"));
    if (first) {
      worker_id = chunk.worker_id();
      lease_id = chunk.lease_id();
    }
    first = false;
    absl::Status added = assembler.add(chunk.offset(), chunk.data(), chunk.total_bytes());
    if (!added.ok()) return to_grpc(added);
    if (chunk.last()) {
      last = true;
      sha256 = chunk.sha256();
      render_seconds = chunk.render_seconds();
      rays = chunk.rays();
      // Sorted by name: a map's wire order is unspecified.
      counters.assign(chunk.counters().begin(), chunk.counters().end());
      std::sort(counters.begin(), counters.end());
    }
  }
  if (first) return to_grpc(absl::InvalidArgumentError("the result upload has no chunks"));
  if (!last) {
    return to_grpc(absl::InvalidArgumentError(
        absl::StrCat("the result for lease ", lease_id, " ended without its last chunk")));
  }
  absl::StatusOr<std::string> bytes = assembler.finish(sha256);
  if (!bytes.ok()) return to_grpc(bytes.status());
  absl::StatusOr<CompleteResult> result = farm_.complete(worker_id, lease_id, *std::move(bytes),
                                                         sha256, render_seconds, rays, counters);
  if (!result.ok()) return to_grpc(result.status());
  response->set_accepted(*result == CompleteResult::kAccepted);
  return grpc::Status::OK;
}

grpc::Status WorkerServiceImpl::FailTask(grpc::ServerContext* context,
                                         const prism::v1::FailTaskRequest* request,
                                         prism::v1::FailTaskResponse*) {
  if (auto auth = check_bearer(*context, worker_secret_); !auth.ok())
    return refused(*context, auth);
  absl::StatusOr<FailureClass> failure_class = failure_class_of(request->failure_class());
  if (!failure_class.ok()) return to_grpc(failure_class.status());
  return to_grpc(
      farm_.fail(request->worker_id(), request->lease_id(), *failure_class, request->message()));
}

grpc::Status WorkerServiceImpl::Leave(grpc::ServerContext* context,
                                      const prism::v1::LeaveRequest* request,
                                      prism::v1::LeaveResponse*) {
  if (auto auth = check_bearer(*context, worker_secret_); !auth.ok())
    return refused(*context, auth);
  return to_grpc(farm_.leave(request->worker_id()));
}

grpc::Status WorkerServiceImpl::FetchBundle(grpc::ServerContext* context,
                                            const prism::v1::FetchBundleRequest* request,
                                            grpc::ServerWriter<prism::v1::BundleData>* writer) {
  if (auto auth = check_bearer(*context, worker_secret_); !auth.ok())
    return refused(*context, auth);
  absl::StatusOr<std::string> bytes = farm_.bundle_bytes(request->bundle_hash());
  if (!bytes.ok()) return to_grpc(bytes.status());
  std::uint64_t offset = 0;
  for (std::string_view piece : prism::rpc::split_chunks(*bytes)) {
    prism::v1::BundleData data;
    data.set_offset(offset);
    data.set_data(std::string(piece));
    data.set_total_bytes(bytes->size());
    offset += piece.size();
    if (!writer->Write(data)) break;  // the worker went away
  }
  return grpc::Status::OK;
}

}  // namespace prism::coordinator::rpc
