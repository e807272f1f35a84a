#include "client/farm_commands.h"

#include <fcntl.h>
#include <grpcpp/create_channel.h>
#include <unistd.h>

#include <cerrno>
#include <condition_variable>
#include <cstdlib>
#include <cstring>
#include <fstream>
#include <map>
#include <mutex>
#include <nlohmann/json.hpp>
#include <thread>

#include "absl/strings/match.h"
#include "absl/strings/str_cat.h"
#include "absl/strings/str_format.h"
#include "client/auto_integrator.h"
#include "coordinator/outputs.h"
#include "google/protobuf/util/json_util.h"
#include "prism/v1/farm.grpc.pb.h"
#include "services/base/atomic_file.h"
#include "services/base/sha256.h"
#include "services/base/status.h"
#include "services/job/job_spec.h"
#include "services/rpc/address.h"
#include "services/rpc/auth.h"
#include "services/rpc/chunks.h"
#include "services/rpc/credentials.h"
#include "services/rpc/result_download.h"
#include "services/rpc/status_mapping.h"
#include "services/scene/bundle.h"
#include "services/scene/scene_loader.h"
#include "services/spectral/named_spectra.h"

namespace prism::client {
namespace {

namespace v1 = prism::v1;
namespace fs = std::filesystem;

class Farm {
 public:
  static absl::StatusOr<Farm> connect(const FarmConnection& c) {
    if (c.address.empty()) {
      return absl::InvalidArgumentError(
          "no coordinator address: pass --coordinator HOST:PORT or set PRISM_COORDINATOR");
    }
    PRISM_RETURN_IF_ERROR(rpc::check_address(c.address, "--coordinator", false));
    rpc::ClientTls tls;
    tls.ca_bundle = c.tls_ca;
    PRISM_ASSIGN_OR_RETURN(auto credentials, rpc::channel_credentials(tls));
    return Farm(c, v1::FarmService::NewStub(grpc::CreateCustomChannel(
                       c.address, credentials, rpc::client_channel_arguments())));
  }

  std::unique_ptr<grpc::ClientContext> call() const {
    auto context = std::make_unique<grpc::ClientContext>();
    if (!c_.token.empty()) rpc::add_bearer(*context, c_.token);
    context->set_deadline(std::chrono::system_clock::now() + c_.deadline);
    return context;
  }
  v1::FarmService::Stub& stub() { return *stub_; }
  const FarmConnection& connection() const { return c_; }

 private:
  Farm(const FarmConnection& c, std::unique_ptr<v1::FarmService::Stub> stub)
      : c_(c), stub_(std::move(stub)) {}
  FarmConnection c_;
  std::unique_ptr<v1::FarmService::Stub> stub_;
};

// The server's message verbatim (the caller prints "prism: <message>"). A plaintext client
// that reaches a TLS coordinator sees only its socket closed: that case says what to try.
absl::Status rpc_error(const Farm& farm, const grpc::Status& status) {
  absl::Status error = rpc::from_grpc(status);
  if (status.error_code() == grpc::StatusCode::UNAVAILABLE && farm.connection().tls_ca.empty() &&
      (absl::StrContains(status.error_message(), "Socket closed") ||
       absl::StrContains(status.error_message(), "Connection reset"))) {
    return absl::Status(
        error.code(),
        absl::StrCat(error.message(), " (if the coordinator at ", farm.connection().address,
                     " serves TLS, give its certificate's CA with --tls-ca)"));
  }
  return error;
}

std::string state_name(v1::JobState state) {
  std::string name = v1::JobState_Name(state);
  constexpr std::string_view kPrefix = "JOB_STATE_";
  if (name.rfind(kPrefix, 0) == 0) name = name.substr(kPrefix.size());
  for (char& ch : name) ch = static_cast<char>(std::tolower(static_cast<unsigned char>(ch)));
  return name;
}

std::string human(double v) {
  if (!(v >= 0)) return "?";
  if (v >= 1e9) return absl::StrFormat("%.2fG", v / 1e9);
  if (v >= 1e6) return absl::StrFormat("%.2fM", v / 1e6);
  if (v >= 1e3) return absl::StrFormat("%.2fk", v / 1e3);
  return absl::StrFormat("%.0f", v);
}

std::string eta(double seconds) {
  if (!(seconds >= 0)) return "?";
  const long s = static_cast<long>(seconds + 0.5);
  return absl::StrFormat("%ld:%02ld", s / 60, s % 60);
}

std::string job_line(const v1::JobInfo& job) {
  const v1::JobProgress& p = job.progress();
  const double percent =
      p.samples_total() > 0 ? 100.0 * static_cast<double>(p.samples_done()) / p.samples_total() : 0;
  std::string line = absl::StrFormat(
      "%s  %-11s %5.1f%%  %llu/%llu tasks  %s", job.job_id(), state_name(job.state()), percent,
      static_cast<unsigned long long>(p.tasks_done()),
      static_cast<unsigned long long>(p.tasks_total()),
      job.spec().name().empty() ? job.spec().scene_path() : job.spec().name());
  if (!job.error().empty()) absl::StrAppend(&line, "  error: ", job.error());
  if (!job.waiting().empty()) absl::StrAppend(&line, "  waiting: ", job.waiting());
  return line;
}

bool finished(v1::JobState s) {
  return s == v1::JOB_STATE_DONE || s == v1::JOB_STATE_FAILED || s == v1::JOB_STATE_CANCELLED;
}

absl::Status job_outcome(const v1::JobInfo& job) {
  if (job.state() == v1::JOB_STATE_FAILED) {
    return absl::AbortedError(absl::StrCat("job ", job.job_id(), " failed: ", job.error()));
  }
  if (job.state() == v1::JOB_STATE_CANCELLED) {
    return absl::CancelledError(absl::StrCat("job ", job.job_id(), " was cancelled"));
  }
  return absl::OkStatus();
}

absl::Status upload_if_missing(Farm& farm, const std::string& hash, const std::string& blob,
                               std::ostream* log) {
  v1::HasBundleRequest has;
  has.set_bundle_hash(hash);
  v1::HasBundleResponse present;
  if (grpc::Status s = farm.stub().HasBundle(farm.call().get(), has, &present); !s.ok()) {
    return rpc_error(farm, s);
  }
  if (present.present()) return absl::OkStatus();
  if (log != nullptr) *log << "uploading bundle " << hash << " (" << blob.size() << " bytes)\n";
  auto context = farm.call();
  context->set_deadline(std::chrono::system_clock::now() + farm.connection().deadline +
                        std::chrono::seconds(blob.size() >> 20));
  v1::UploadBundleResponse response;
  auto writer = farm.stub().UploadBundle(context.get(), &response);
  for (std::string_view chunk : rpc::split_chunks(blob)) {
    v1::BundleChunk message;
    message.set_bundle_hash(hash);
    message.set_total_bytes(blob.size());
    message.set_data(std::string(chunk));
    if (!writer->Write(message)) break;  // the server's status follows from Finish()
  }
  writer->WritesDone();
  if (grpc::Status s = writer->Finish(); !s.ok()) return rpc_error(farm, s);
  if (response.bundle_hash() != hash) {
    return absl::DataLossError(
        absl::StrCat("the coordinator stored bundle ", response.bundle_hash(), ", not ", hash));
  }
  return absl::OkStatus();
}

// A job's fetched files, all or none: each is written to a temporary beside its name, and only
// when every one is written are they renamed into place. A full disk used to leave the spectral
// EXR without its RGB EXR, PNG and report, and said only "could not write".
class StagedFiles {
 public:
  ~StagedFiles() {
    std::error_code ignored;
    for (const auto& [temp, path] : staged_) fs::remove(temp, ignored);
  }
  absl::Status add(const fs::path& path, const std::string& bytes) {
    const fs::path temp = path.parent_path() / (".fetch." + path.filename().string() + ".part." +
                                                std::to_string(::getpid()));
    const int fd = ::open(temp.c_str(), O_WRONLY | O_CREAT | O_TRUNC | O_CLOEXEC, 0644);
    if (fd < 0) {
      return absl::UnavailableError(
          absl::StrCat("could not write ", path.string(), ": ", std::strerror(errno)));
    }
    staged_.emplace_back(temp, path);
    absl::Status status = base::pwrite_all(fd, bytes.data(), bytes.size(), 0, path.string());
    if (::close(fd) != 0 && status.ok()) {
      status = absl::InternalError(std::strerror(errno));
    }
    if (!status.ok()) {
      return absl::UnavailableError(
          absl::StrCat("could not write ", path.string(), ": ", status.message()));
    }
    return absl::OkStatus();
  }
  absl::Status commit() {
    for (const auto& [temp, path] : staged_) {
      std::error_code error;
      fs::rename(temp, path, error);
      if (error) {
        return absl::UnavailableError(
            absl::StrCat("could not write ", path.string(), ": ", error.message()));
      }
    }
    staged_.clear();
    return absl::OkStatus();
  }

 private:
  std::vector<std::pair<fs::path, fs::path>> staged_;
};

absl::StatusOr<v1::JobInfo> get_job(Farm& farm, const std::string& id) {
  v1::GetJobRequest request;
  request.set_job_id(id);
  v1::JobInfo job;
  if (grpc::Status s = farm.stub().GetJob(farm.call().get(), request, &job); !s.ok()) {
    return rpc_error(farm, s);
  }
  return job;
}

absl::StatusOr<v1::JobInfo> watch(Farm& farm, const std::string& id, std::ostream& out,
                                  bool terminal) {
  auto context = std::make_unique<grpc::ClientContext>();
  if (!farm.connection().token.empty()) rpc::add_bearer(*context, farm.connection().token);
  v1::WatchJobRequest request;
  request.set_job_id(id);
  // A per-message deadline: the server writes only when the job changes, so when no event
  // arrives in time a watchdog asks GetJob (itself under a deadline) whether the coordinator is
  // still there; if it is not, the watch is cancelled with that error.
  auto reader = farm.stub().WatchJob(context.get(), request);
  v1::JobInfo job, last;
  bool any = false;
  std::mutex mu;
  std::condition_variable cv;
  auto last_message = std::chrono::steady_clock::now();
  bool done = false;
  absl::Status lost;
  std::thread watchdog([&] {
    std::unique_lock lock(mu);
    while (!done) {
      const auto due = last_message + farm.connection().deadline;
      if (cv.wait_until(lock, due, [&] { return done; })) return;
      if (std::chrono::steady_clock::now() < last_message + farm.connection().deadline) continue;
      lock.unlock();
      absl::StatusOr<v1::JobInfo> probe = get_job(farm, id);
      lock.lock();
      if (probe.ok()) {
        last_message = std::chrono::steady_clock::now();
        continue;
      }
      lost = probe.status();
      context->TryCancel();
      return;
    }
  });
  while (reader->Read(&job)) {
    {
      std::lock_guard lock(mu);
      last_message = std::chrono::steady_clock::now();
    }
    any = true;
    last = job;
    const v1::JobProgress& p = job.progress();
    const double fraction =
        p.samples_total() > 0 ? static_cast<double>(p.samples_done()) / p.samples_total() : 0.0;
    // A finished job has no rate or time left to show (it said "0 samples/s eta 0:00").
    const bool ended = finished(job.state());
    if (terminal) {
      constexpr int kWidth = 30;
      const int filled = static_cast<int>(fraction * kWidth);
      out << "\r[" << std::string(filled, '#') << std::string(kWidth - filled, ' ') << "] "
          << absl::StrFormat("%5.1f%%", 100 * fraction) << " " << state_name(job.state());
      if (!ended) {
        out << " " << human(p.samples_per_second()) << " samples/s ETA " << eta(p.eta_seconds());
      }
      out << "   " << std::flush;
    } else {
      out << job.job_id() << " " << state_name(job.state())
          << absl::StrFormat(" %.1f%%", 100 * fraction);
      if (!ended) {
        out << " " << human(p.samples_per_second()) << " samples/s eta " << eta(p.eta_seconds());
      }
      out << "\n" << std::flush;
    }
    if (finished(job.state())) break;
  }
  if (terminal) out << "\n";
  {
    std::lock_guard lock(mu);
    done = true;
  }
  cv.notify_all();
  watchdog.join();
  if (any && finished(last.state())) {
    context->TryCancel();
    reader->Finish();
    return last;
  }
  grpc::Status status = reader->Finish();
  if (!lost.ok()) return lost;
  if (!status.ok()) return rpc_error(farm, status);
  // The stream ended before a final state: ask once.
  return get_job(farm, id);
}

// watch(), through a coordinator that goes away and comes back (a restart, a rescheduled pod):
// while the address answers UNAVAILABLE (or not at all) it tries again every two seconds for up to
// kCoordinatorPatience, saying so once; the job goes on there, resumed from its data directory.
constexpr std::chrono::minutes kCoordinatorPatience{5};

absl::StatusOr<v1::JobInfo> watch_through_restarts(Farm& farm, const std::string& id,
                                                   std::ostream& out, bool terminal,
                                                   const v1::JobInfo* submitted = nullptr) {
  using Clock = std::chrono::steady_clock;
  // What makes the job this one: an id alone is not, when the coordinator that comes back
  // has another data directory (its first job is j-000001 too).
  auto identity = [](const v1::JobInfo& j) {
    return absl::StrCat(j.spec().bundle_hash(), "|", j.spec().scene_path(), "|",
                        j.submitted_unix_ms());
  };
  std::optional<std::string> known;
  if (submitted != nullptr) {
    known = identity(*submitted);  // as SubmitJob answered, before anything could go away
  } else if (absl::StatusOr<v1::JobInfo> first = get_job(farm, id); first.ok()) {
    known = identity(*first);
  }
  std::optional<Clock::time_point> give_up_at;
  bool reconnecting = false;
  for (;;) {
    if (reconnecting) {
      absl::StatusOr<v1::JobInfo> back = get_job(farm, id);
      if (back.ok() && known.has_value() && identity(*back) != *known) {
        return absl::FailedPreconditionError(absl::StrCat(
            "the coordinator at ", farm.connection().address, " came back with another job ", id,
            " (scene ", back->spec().scene_path(), ", submitted at ", back->submitted_unix_ms(),
            " ms): it started on another data directory, and this job is not there"));
      }
      if (back.ok() && !known.has_value()) known = identity(*back);
      if (!back.ok() && back.status().code() == absl::StatusCode::kNotFound) {
        return absl::FailedPreconditionError(absl::StrCat(
            "the coordinator at ", farm.connection().address, " came back without job ", id,
            ": it started on another data directory, and this job is not there"));
      }
    }
    const Clock::time_point started = Clock::now();
    absl::StatusOr<v1::JobInfo> job = watch(farm, id, out, terminal);
    if (job.ok() || (job.status().code() != absl::StatusCode::kUnavailable &&
                     job.status().code() != absl::StatusCode::kDeadlineExceeded)) {
      return job;
    }
    // A watch that ran a while was connected: a new outage starts a new wait.
    if (Clock::now() - started > std::chrono::seconds(10)) give_up_at.reset();
    if (!give_up_at.has_value()) {
      give_up_at = Clock::now() + kCoordinatorPatience;
      out << "the coordinator at " << farm.connection().address << " is unreachable ("
          << job.status().message() << "); job " << id
          << " goes on when it is back: trying again for up to 5 minutes\n"
          << std::flush;
    }
    if (Clock::now() >= *give_up_at) {
      return absl::UnavailableError(
          absl::StrCat(job.status().message(), " (for 5 minutes); job ", id,
                       " goes on when the coordinator is back: follow it with `prism watch ", id,
                       "` and get its outputs with `prism fetch ", id, "`"));
    }
    std::this_thread::sleep_for(std::chrono::seconds(2));
    reconnecting = true;
  }
}

// The job's report names the files in the coordinator's data directory; the fetched copy names
// the files it was fetched to, as `prism render`'s report does (same keys, same layout). A
// report that does not parse is kept as it came.
std::string with_local_outputs(const std::string& report, const coordinator::OutputPaths& paths) {
  nlohmann::ordered_json j = nlohmann::ordered_json::parse(report, nullptr, false);
  if (j.is_discarded() || !j.is_object() || !j.contains("outputs") || !j["outputs"].is_object()) {
    return report;
  }
  const std::pair<const char*, const fs::path*> local[] = {{"spectral_exr", &paths.spectral_exr},
                                                           {"rgb_exr", &paths.rgb_exr},
                                                           {"png", &paths.png},
                                                           {"json", &paths.json},
                                                           {"primal_exr", &paths.primal_exr},
                                                           {"gradient_exr", &paths.gradient_exr},
                                                           {"filtered_exr", &paths.filtered_exr},
                                                           {"filtered_png", &paths.filtered_png}};
  for (const auto& [key, path] : local) {
    if (j["outputs"].contains(key)) j["outputs"][key] = path->string();
  }
  return j.dump(2) + "\n";
}

// The Film filename a job's report records (report.cpp "film_filename"), or "" when it has none.
std::string report_film_filename(const std::string& report) {
  const nlohmann::json j = nlohmann::json::parse(report, nullptr, false);
  if (j.is_discarded() || !j.is_object() || !j.contains("film_filename") ||
      !j["film_filename"].is_string()) {
    return "";
  }
  return j["film_filename"].get<std::string>();
}

// `film_filename`: the default name's source, as in `prism render`: the scene's Film filename
// when the scene is at hand; else ("") the one the job's report records, else render.exr.
absl::StatusOr<std::string> fetch(Farm& farm, const std::string& id,
                                  const std::optional<fs::path>& output,
                                  const std::string& film_filename = "") {
  PRISM_ASSIGN_OR_RETURN(
      coordinator::OutputPaths paths,
      coordinator::output_paths(output, std::nullopt,
                                film_filename.empty() ? "render.exr" : film_filename));
  PRISM_RETURN_IF_ERROR(coordinator::check_output_locations(paths));
  auto context = farm.call();
  context->set_deadline(std::chrono::system_clock::now() + farm.connection().deadline * 4);
  v1::GetResultRequest request;
  request.set_job_id(id);
  auto reader = farm.stub().GetResult(context.get(), request);
  absl::StatusOr<rpc::ResultFiles> read = rpc::read_result_files(*reader);
  if (!read.ok()) {
    context->TryCancel();
    reader->Finish();
    return read.status();
  }
  if (grpc::Status s = reader->Finish(); !s.ok()) return rpc_error(farm, s);
  if (read->ended_inside_a_file)
    return absl::DataLossError("the result stream ended inside a file");
  // Without -o, or with -o naming a directory, the default name (output_paths).
  std::error_code ec;
  const bool default_name =
      !output.has_value() || !output->has_filename() || fs::is_directory(*output, ec);
  if (default_name && film_filename.empty()) {
    const auto report = read->files.find(v1::OUTPUT_KIND_REPORT_JSON);
    const std::string named =
        report != read->files.end() ? report_film_filename(report->second) : std::string();
    if (!named.empty()) {
      PRISM_ASSIGN_OR_RETURN(paths, coordinator::output_paths(output, std::nullopt, named));
      PRISM_RETURN_IF_ERROR(coordinator::check_output_locations(paths));
    }
  }
  std::string written;
  StagedFiles staged;
  for (auto& [kind, bytes] : read->files) {
    fs::path path;
    switch (kind) {
      case v1::OUTPUT_KIND_SPECTRAL_EXR:
        path = paths.spectral_exr;
        break;
      case v1::OUTPUT_KIND_RGB_EXR:
        path = paths.rgb_exr;
        break;
      case v1::OUTPUT_KIND_PNG:
        path = paths.png;
        break;
      case v1::OUTPUT_KIND_REPORT_JSON:
        path = paths.json;
        break;
      case v1::OUTPUT_KIND_PRIMAL_EXR:
        path = paths.primal_exr;
        break;
      case v1::OUTPUT_KIND_GRADIENT_EXR:
        path = paths.gradient_exr;
        break;
      case v1::OUTPUT_KIND_FILTERED_EXR:
        path = paths.filtered_exr;
        break;
      case v1::OUTPUT_KIND_FILTERED_PNG:
        path = paths.filtered_png;
        break;
      default:
        continue;  // outputs this client does not name yet
    }
    if (kind == v1::OUTPUT_KIND_REPORT_JSON) bytes = with_local_outputs(bytes, paths);
    PRISM_RETURN_IF_ERROR(staged.add(path, bytes));
    absl::StrAppend(&written, written.empty() ? "" : ", ", path.string());
  }
  if (written.empty()) return absl::NotFoundError(absl::StrCat("job ", id, " has no outputs"));
  PRISM_RETURN_IF_ERROR(staged.commit());
  return absl::StrCat("wrote ", written, "\n");
}

}  // namespace

absl::Status resolve_connection(FarmConnection& c) {
  if (c.address.empty()) {
    if (const char* env = std::getenv("PRISM_COORDINATOR")) c.address = env;
  }
  if (c.token.empty()) {
    if (const char* env = std::getenv("PRISM_API_TOKEN")) c.token = env;
  }
  if (c.address.empty()) {
    return absl::InvalidArgumentError(
        "no coordinator address: pass --coordinator HOST:PORT or set PRISM_COORDINATOR");
  }
  return absl::OkStatus();
}

namespace {

// What submitting a scene sends: the packed bundle and the request with its explicit spec and
// client token, and the scene's own output name (for --wait's -o default).
struct Submission {
  scene::Bundle bundle;
  v1::SubmitJobRequest request;
  std::string film_filename;
  // The scene's directory and files (SceneDescription::files), which no output may replace.
  std::filesystem::path root;
  std::vector<std::string> files;
};

absl::StatusOr<Submission> prepare_submission(const SubmitOptions& options) {
  PRISM_RETURN_IF_ERROR(validate_render_flags(options.render));
  PRISM_ASSIGN_OR_RETURN(spectral::SpectrumLibrary library,
                         spectral::SpectrumLibrary::load_builtin());
  scene::LoadOptions load = scene::with_library_names(library);
  load.allow_unsupported = options.render.allow_unsupported;
  PRISM_ASSIGN_OR_RETURN(scene::LoadedScene loaded, scene::load_scene(options.render.scene, load));
  if (options.render.warnings != nullptr) {
    for (const std::string& w : loaded.description.warnings) *options.render.warnings << w << "\n";
    for (const std::string& w : scene::feature_warnings(loaded.description.features, false))
      *options.render.warnings << w << "\n";
  }
  Submission out;
  out.film_filename = loaded.description.film.filename;
  out.root = loaded.root;
  out.files = loaded.description.files;
  PRISM_ASSIGN_OR_RETURN(
      out.bundle, scene::make_bundle(loaded.root, loaded.scene_relpath, loaded.description.files));
  if (options.wait) {
    // Checked before anything is submitted, so a bad -o does not leave a job behind.
    PRISM_ASSIGN_OR_RETURN(
        coordinator::OutputPaths paths,
        coordinator::output_paths(options.render.output, std::nullopt, out.film_filename));
    PRISM_RETURN_IF_ERROR(coordinator::check_output_locations(paths));
    PRISM_RETURN_IF_ERROR(
        coordinator::check_outputs_spare_scene(paths, loaded.root, loaded.description.files));
  }
  // `auto` and the τ pilot run here, so the job carries their choices and every worker traces
  // with them.
  std::optional<worker::EmbreeDevice> device;
  ResolvedIntegrator resolved{options.render, std::nullopt, std::nullopt, nullptr};
  if (options.render.integrator == "auto") {
    device.emplace();
    PRISM_ASSIGN_OR_RETURN(resolved,
                           resolve_integrator(options.render, *device, loaded.description, library,
                                              out.bundle.content_hash, loaded.scene_relpath));
  }
  PRISM_ASSIGN_OR_RETURN(v1::JobSpec spec,
                         job_spec_of(resolved.options, loaded.description, out.bundle.content_hash,
                                     loaded.scene_relpath));
  if (resolved.report.has_value()) set_auto_choice(*resolved.report, spec);
  if (spec.integrator() == v1::INTEGRATOR_GRADIENT && !resolved.options.tau.has_value()) {
    // The pilot runs here, so the job carries its τ and every worker traces with it.
    if (!device.has_value()) device.emplace();
    PRISM_RETURN_IF_ERROR(choose_or_reuse_tau(resolved.options, resolved.tau_pilot, *device,
                                              loaded.description, library, spec)
                              .status());
  }
  *out.request.mutable_spec() = spec;
  if (options.client_token.empty()) {
    out.request.set_client_token(
        base::sha256_hex(absl::StrCat(out.bundle.content_hash, "\n", job::request_identity(spec))));
  } else {
    out.request.set_client_token(options.client_token);
  }
  return out;
}

}  // namespace

absl::StatusOr<std::string> run_pack(const SubmitOptions& options,
                                     const std::filesystem::path& bundle_file) {
  PRISM_ASSIGN_OR_RETURN(Submission submission, prepare_submission(options));
  PRISM_RETURN_IF_ERROR(
      coordinator::check_not_a_scene_file(bundle_file, submission.root, submission.files));
  PRISM_RETURN_IF_ERROR(coordinator::check_not_special_file(bundle_file));
  const std::string packed = scene::pack(submission.bundle);
  PRISM_RETURN_IF_ERROR(base::write_file_atomic(bundle_file, packed));
  google::protobuf::util::JsonPrintOptions print;
  print.add_whitespace = true;
  std::string json;
  if (auto printed = google::protobuf::util::MessageToJsonString(submission.request, &json, print);
      !printed.ok()) {
    return absl::InternalError(std::string(printed.message()));
  }
  return json;
}

absl::StatusOr<std::string> run_submit(const FarmConnection& c, const SubmitOptions& options) {
  PRISM_ASSIGN_OR_RETURN(Farm farm, Farm::connect(c));
  PRISM_ASSIGN_OR_RETURN(Submission submission, prepare_submission(options));
  const std::string packed = scene::pack(submission.bundle);
  const v1::SubmitJobRequest& request = submission.request;
  std::ostream null_stream(nullptr);
  std::ostream& out = options.progress != nullptr ? *options.progress : null_stream;
  v1::SubmitJobResponse response;
  // With --wait a coordinator going away during the submission (the bundle's upload or the
  // request) is ridden out as during the watch: both are sent again, the request's client token
  // finding the job if it was stored before the answer was lost.
  const auto give_up_at = std::chrono::steady_clock::now() + kCoordinatorPatience;
  for (bool said = false;;) {
    absl::Status error =
        upload_if_missing(farm, submission.bundle.content_hash, packed, options.progress);
    if (error.ok()) {
      grpc::Status s = farm.stub().SubmitJob(farm.call().get(), request, &response);
      if (s.ok()) break;
      error = rpc_error(farm, s);
    }
    // A connection cut mid-stream can also end as INTERNAL ("Socket closed", "Connection reset").
    const bool unreachable = error.code() == absl::StatusCode::kUnavailable ||
                             error.code() == absl::StatusCode::kDeadlineExceeded ||
                             error.code() == absl::StatusCode::kInternal;
    if (!options.wait || !unreachable || std::chrono::steady_clock::now() > give_up_at) {
      return error;
    }
    if (!said) {
      out << "the coordinator at " << farm.connection().address << " is unreachable ("
          << error.message() << "); submitting again every 2 s for up to 5 minutes\n"
          << std::flush;
      said = true;
    }
    std::this_thread::sleep_for(std::chrono::seconds(2));
  }
  const std::string id = response.job().job_id();
  if (!options.wait) return id + "\n";
  out << id << "\n";
  PRISM_ASSIGN_OR_RETURN(
      v1::JobInfo job,
      watch_through_restarts(farm, id, out, options.progress_is_terminal, &response.job()));
  PRISM_RETURN_IF_ERROR(job_outcome(job));
  PRISM_ASSIGN_OR_RETURN(std::string written,
                         fetch(farm, id, options.render.output, submission.film_filename));
  return absl::StrCat(id, "\n", written);
}

absl::StatusOr<std::string> run_status(const FarmConnection& c, const std::string& job_id) {
  PRISM_ASSIGN_OR_RETURN(Farm farm, Farm::connect(c));
  PRISM_ASSIGN_OR_RETURN(v1::JobInfo job, get_job(farm, job_id));
  const v1::JobProgress& p = job.progress();
  std::string text = absl::StrCat(job_line(job), "\n");
  absl::StrAppend(&text, "samples ", p.samples_done(), "/", p.samples_total(), ", tiles ",
                  p.tiles_finalised(), "/", p.tiles_total(), ", ", human(p.samples_per_second()),
                  " samples/s, eta ", eta(p.eta_seconds()), "\n");
  return text;
}

absl::StatusOr<std::string> run_jobs(const FarmConnection& c) {
  PRISM_ASSIGN_OR_RETURN(Farm farm, Farm::connect(c));
  v1::ListJobsRequest request;
  v1::ListJobsResponse response;
  if (grpc::Status s = farm.stub().ListJobs(farm.call().get(), request, &response); !s.ok()) {
    return rpc_error(farm, s);
  }
  std::string text;
  for (const v1::JobInfo& job : response.jobs()) absl::StrAppend(&text, job_line(job), "\n");
  if (text.empty()) text = "no jobs\n";
  return text;
}

absl::StatusOr<std::string> run_watch(const FarmConnection& c, const std::string& job_id,
                                      std::ostream& out, bool terminal) {
  PRISM_ASSIGN_OR_RETURN(Farm farm, Farm::connect(c));
  PRISM_ASSIGN_OR_RETURN(v1::JobInfo job, watch_through_restarts(farm, job_id, out, terminal));
  PRISM_RETURN_IF_ERROR(job_outcome(job));
  return absl::StrCat(job_line(job), "\n");
}

absl::StatusOr<std::string> run_cancel(const FarmConnection& c, const std::string& job_id) {
  PRISM_ASSIGN_OR_RETURN(Farm farm, Farm::connect(c));
  v1::CancelJobRequest request;
  request.set_job_id(job_id);
  v1::JobInfo job;
  if (grpc::Status s = farm.stub().CancelJob(farm.call().get(), request, &job); !s.ok()) {
    return rpc_error(farm, s);
  }
  return absl::StrCat(job_line(job), "\n");
}

absl::StatusOr<std::string> run_fetch(const FarmConnection& c, const std::string& job_id,
                                      const std::optional<fs::path>& output) {
  PRISM_ASSIGN_OR_RETURN(Farm farm, Farm::connect(c));
  return fetch(farm, job_id, output);
}

absl::StatusOr<std::string> run_workers(const FarmConnection& c) {
  PRISM_ASSIGN_OR_RETURN(Farm farm, Farm::connect(c));
  v1::ListWorkersRequest request;
  v1::ListWorkersResponse response;
  if (grpc::Status s = farm.stub().ListWorkers(farm.call().get(), request, &response); !s.ok()) {
    return rpc_error(farm, s);
  }
  std::string text;
  for (const v1::WorkerInfo& w : response.workers()) {
    absl::StrAppend(&text, w.worker_id(), "  ", w.host(), "  ", w.state(), "  ", w.threads(),
                    " threads  ", w.tasks_completed(), " tasks  ", w.version());
    if (!w.current_task().empty()) {
      absl::StrAppend(&text, "  lease ", w.current_lease(), ": ", w.current_task());
      if (w.leases() > 1) absl::StrAppend(&text, " (+", w.leases() - 1, " more)");
    }
    absl::StrAppend(&text, "\n");
  }
  if (text.empty()) text = "no workers\n";
  return text;
}

absl::StatusOr<int> live_workers(const FarmConnection& c) {
  PRISM_ASSIGN_OR_RETURN(Farm farm, Farm::connect(c));
  v1::ListWorkersRequest request;
  v1::ListWorkersResponse response;
  if (grpc::Status s = farm.stub().ListWorkers(farm.call().get(), request, &response); !s.ok()) {
    return rpc_error(farm, s);
  }
  int live = 0;
  for (const v1::WorkerInfo& w : response.workers()) {
    live += w.state() == "idle" || w.state() == "busy" ? 1 : 0;
  }
  return live;
}

}  // namespace prism::client
