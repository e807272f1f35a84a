// The farm subcommands of `prism`: submit (and pack), status, jobs, watch, cancel, fetch, workers.
// Each is a thin client of the coordinator's FarmService (proto/prism/v1/farm.proto). Every RPC
// carries a deadline (a watch, one per message) and the bearer token; a failed RPC returns the
// server's message as an absl::Status so `prism` prints it verbatim and exits non-zero.
//
// Submit is idempotent: the bundle is content addressed (uploaded only when HasBundle says it
// is missing) and the default client token is a SHA-256 of the bundle hash and the spec's bytes,
// so submitting the same scene with the same options returns the same job.
#pragma once

#include <chrono>
#include <filesystem>
#include <optional>
#include <ostream>
#include <string>

#include "absl/status/statusor.h"
#include "client/render_command.h"

namespace prism::client {

struct FarmConnection {
  std::string address;                        // --coordinator, else $PRISM_COORDINATOR
  std::string token;                          // --token, else $PRISM_API_TOKEN
  std::filesystem::path tls_ca;               // empty: plaintext
  std::chrono::milliseconds deadline{30000};  // per unary RPC / per streamed message
};

// Fills the address and token from the environment where the flags left them empty;
// INVALID_ARGUMENT when there is still no address.
absl::Status resolve_connection(FarmConnection& connection);

struct SubmitOptions {
  RenderCommandOptions render;  // scene, -o and the render flags (threads/json ignored)
  std::string client_token;     // empty: derived from bundle hash + spec
  bool wait = false;
  // Notes ("uploading bundle ...") and, with wait, the watch output; null: none.
  std::ostream* progress = nullptr;
  bool progress_is_terminal = false;
};

// Prints the job id (one line); with wait, watches and fetches like `prism fetch`.
absl::StatusOr<std::string> run_submit(const FarmConnection& c, const SubmitOptions& options);
// `prism pack`: what submit would send, for clients of the HTTP API (curl, scripts): writes the
// packed bundle to `bundle_file` (atomically) and returns the SubmitJobRequest as JSON, its spec
// explicit as submit makes it (auto and the τ pilot resolved). Nothing is contacted.
absl::StatusOr<std::string> run_pack(const SubmitOptions& options,
                                     const std::filesystem::path& bundle_file);
absl::StatusOr<std::string> run_status(const FarmConnection& c, const std::string& job_id);
absl::StatusOr<std::string> run_jobs(const FarmConnection& c);
// Progress to `out` (a bar when `terminal`, else a line per update); FAILED/CANCELLED is an
// error carrying the job's error message.
absl::StatusOr<std::string> run_watch(const FarmConnection& c, const std::string& job_id,
                                      std::ostream& out, bool terminal);
absl::StatusOr<std::string> run_cancel(const FarmConnection& c, const std::string& job_id);
// Writes the outputs named as `prism render` names them from `output` (out.exr, out.rgb.exr,
// out.png, out.json), each verified against its SHA-256 and written atomically.
absl::StatusOr<std::string> run_fetch(const FarmConnection& c, const std::string& job_id,
                                      const std::optional<std::filesystem::path>& output);
absl::StatusOr<std::string> run_workers(const FarmConnection& c);
// How many of the farm's workers can take tasks (idle or busy; not draining or lost).
absl::StatusOr<int> live_workers(const FarmConnection& c);

}  // namespace prism::client
