#include "coordinator/http/http_api.h"

#include <httplib.h>

#include <algorithm>
#include <cerrno>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <functional>
#include <map>
#include <regex>

#include "absl/strings/ascii.h"
#include "absl/strings/numbers.h"
#include "absl/strings/str_cat.h"
#include "absl/strings/str_join.h"
#include "coordinator/http/api_routes.h"
#include "coordinator/http/dashboard_assets.h"
#include "coordinator/resource_plan.h"
#include "coordinator/rpc/farm_service.h"
#include "google/protobuf/util/json_util.h"
#include "prism/v1/farm.pb.h"
#include "services/base/check.h"
#include "services/base/sha256.h"
#include "services/base/status.h"
#include "services/rpc/auth.h"

namespace prism::coordinator::http {
namespace {

namespace v1 = prism::v1;
using Handler = std::function<void(const httplib::Request&, httplib::Response&)>;

int http_status(absl::StatusCode code) {
  switch (code) {
    case absl::StatusCode::kOk:
      return 200;
    case absl::StatusCode::kInvalidArgument:
    case absl::StatusCode::kOutOfRange:
      return 400;
    case absl::StatusCode::kUnauthenticated:
      return 401;
    case absl::StatusCode::kPermissionDenied:
      return 403;
    case absl::StatusCode::kNotFound:
      return 404;
    case absl::StatusCode::kAlreadyExists:
    case absl::StatusCode::kAborted:
      return 409;
    case absl::StatusCode::kFailedPrecondition:
      return 409;  // the resource's state does not allow it (a done job's cancel)
    case absl::StatusCode::kResourceExhausted:
      return 429;
    case absl::StatusCode::kCancelled:
      return 499;
    case absl::StatusCode::kUnimplemented:
      return 501;
    case absl::StatusCode::kUnavailable:
      return 503;
    case absl::StatusCode::kDeadlineExceeded:
      return 504;
    default:
      return 500;
  }
}

std::string to_json(const google::protobuf::Message& message) {
  google::protobuf::util::JsonPrintOptions options;
  options.always_print_primitive_fields = true;
  std::string out;
  PRISM_CHECK(google::protobuf::util::MessageToJsonString(message, &out, options).ok());
  return out;
}

void send_message(httplib::Response& res, const google::protobuf::Message& message) {
  res.status = 200;
  res.set_content(to_json(message), "application/json");
}

void send_error(httplib::Response& res, const absl::Status& status) {
  v1::ApiError error;
  error.set_code(absl::StatusCodeToString(status.code()));
  error.set_message(std::string(status.message()));
  res.status = is_permanent_refusal(status) ? 413 : http_status(status.code());
  if (status.code() == absl::StatusCode::kUnauthenticated)
    res.set_header("WWW-Authenticate", "Bearer");
  res.set_content(to_json(error), "application/json");
}

// A route's path template as the regular expression cpp-httplib matches: each {parameter} one
// capture group (no '/', and for ids no ':' either, so "{job_id}:cancel" splits).
std::string path_regex(const std::string& path) {
  std::string out;
  for (std::size_t i = 0; i < path.size(); ++i) {
    const char c = path[i];
    if (c == '{') {
      const std::size_t close = path.find('}', i);
      PRISM_CHECK(close != std::string::npos);
      out += path.substr(i + 1, close - i - 1) == "file_name" ? "([^/]+)" : "([^/:]+)";
      i = close;
    } else if (c == '.' || c == '(' || c == ')' || c == '+' || c == '?' || c == '*') {
      out += '\\';
      out += c;
    } else {
      out += c;
    }
  }
  return out;
}

absl::StatusOr<std::optional<double>> query_number(const httplib::Request& req,
                                                   const std::string& name) {
  if (!req.has_param(name)) return std::optional<double>();
  const std::string value = req.get_param_value(name);
  double number = 0;
  if (!absl::SimpleAtod(value, &number) || !std::isfinite(number)) {
    return absl::InvalidArgumentError(
        absl::StrCat("query parameter ", name, "=", value, " is not a number"));
  }
  return std::optional<double>(number);
}

absl::StatusOr<store::JobState> parse_state(const std::string& value) {
  std::string name = absl::AsciiStrToUpper(value);
  if (name.rfind("JOB_STATE_", 0) != 0) name = "JOB_STATE_" + name;
  v1::JobState state = v1::JOB_STATE_UNSPECIFIED;
  if (!v1::JobState_Parse(name, &state) || state == v1::JOB_STATE_UNSPECIFIED) {
    return absl::InvalidArgumentError(
        absl::StrCat("query parameter state=", value, " is not a job state (e.g. RENDERING)"));
  }
  return static_cast<store::JobState>(static_cast<int>(state));
}

absl::StatusOr<std::pair<std::string, int>> parse_listen(const std::string& listen) {
  const std::size_t colon = listen.rfind(':');
  if (colon == std::string::npos || colon == 0) {
    return absl::InvalidArgumentError(
        absl::StrCat("--http-listen ", listen, ": want host:port (e.g. 127.0.0.1:8080)"));
  }
  std::string host = listen.substr(0, colon);
  if (host.size() > 2 && host.front() == '[' && host.back() == ']')
    host = host.substr(1, host.size() - 2);
  int port = 0;
  if (!absl::SimpleAtoi(listen.substr(colon + 1), &port) || port < 0 || port > 65535) {
    return absl::InvalidArgumentError(
        absl::StrCat("--http-listen ", listen, ": the port is not a number in 0..65535"));
  }
  return std::make_pair(host, port);
}

const char* content_type_of(const std::filesystem::path& file) {
  const std::string ext = file.extension().string();
  if (ext == ".png") return "image/png";
  if (ext == ".json") return "application/json";
  if (ext == ".exr") return "image/x-exr";
  return "application/octet-stream";
}

}  // namespace

HttpApi::HttpApi(FarmCoordinator& farm, HttpConfig config, std::shared_ptr<spdlog::logger> logger)
    : farm_(farm), view_(farm), config_(std::move(config)), logger_(std::move(logger)) {}

absl::StatusOr<std::unique_ptr<HttpApi>> HttpApi::start(FarmCoordinator& farm,
                                                        const HttpConfig& config,
                                                        std::shared_ptr<spdlog::logger> logger) {
  PRISM_ASSIGN_OR_RETURN(auto address, parse_listen(config.listen));
  std::unique_ptr<HttpApi> api(new HttpApi(farm, config, std::move(logger)));
  if (!config.tls.cert_chain.empty()) {
    // The same checks and messages as the gRPC server's credentials, before anything listens.
    PRISM_RETURN_IF_ERROR(prism::rpc::server_credentials(config.tls).status());
    auto server = std::make_unique<httplib::SSLServer>(config.tls.cert_chain.c_str(),
                                                       config.tls.private_key.c_str());
    if (!server->is_valid()) {
      return absl::InvalidArgumentError(absl::StrCat("HTTPS: cannot use the certificate ",
                                                     config.tls.cert_chain.string(), " and key ",
                                                     config.tls.private_key.string()));
    }
    api->server_ = std::move(server);
  } else {
    api->server_ = std::make_unique<httplib::Server>();
  }
  api->server_->new_task_queue = [] { return new httplib::ThreadPool(kThreads); };
  // httplib's default sets SO_REUSEPORT, which lets a second coordinator bind the same address
  // and take a random share of the requests. SO_REUSEADDR alone still allows a restart while
  // the old connections wait in TIME_WAIT, and refuses a second listener.
  api->server_->set_socket_options([](socket_t sock) {
    int yes = 1;
    ::setsockopt(sock, SOL_SOCKET, SO_REUSEADDR, &yes, sizeof(yes));
  });
  api->server_->set_payload_max_length(farm.options().max_bundle_bytes);
  api->install_routes();
  const auto& [host, port] = address;
  if (port == 0) {
    api->port_ = api->server_->bind_to_any_port(host);
  } else if (api->server_->bind_to_port(host, port)) {
    api->port_ = port;
  }
  if (api->port_ <= 0) {
    return absl::UnavailableError(absl::StrCat("cannot listen for HTTP on ", config.listen,
                                               " (is another process using the address?)"));
  }
  HttpApi* self = api.get();
  api->thread_ = std::thread([self] { self->server_->listen_after_bind(); });
  return api;
}

HttpApi::~HttpApi() {
  shutdown();
}

void HttpApi::shutdown() {
  stopping_ = true;
  if (server_ != nullptr) server_->stop();
  if (thread_.joinable()) thread_.join();
}

void HttpApi::install_routes() {
  auto authorised = [this](const httplib::Request& req, httplib::Response& res) {
    const bool present = req.has_header("Authorization");
    const std::string header = req.get_header_value("Authorization");
    absl::Status auth = prism::rpc::check_bearer_value(
        present ? std::optional<std::string_view>(header) : std::nullopt, config_.api_token);
    if (auth.ok()) return true;
    logger_->warn("refused an HTTP call from {}: {}", req.remote_addr, std::string(auth.message()));
    send_error(res, auth);
    return false;
  };

  std::map<std::string, Handler> handlers;
  handlers["listJobs"] = [this](const httplib::Request& req, httplib::Response& res) {
    absl::StatusOr<std::optional<double>> limit = query_number(req, "limit");
    if (!limit.ok()) return send_error(res, limit.status());
    if (limit->has_value() && (**limit < 0 || **limit > 1e9 || **limit != std::floor(**limit))) {
      return send_error(
          res, absl::InvalidArgumentError("query parameter limit is not a whole number in 0..1e9"));
    }
    std::vector<store::JobState> states;
    for (std::size_t i = 0; i < req.get_param_value_count("state"); ++i) {
      absl::StatusOr<store::JobState> state = parse_state(req.get_param_value("state", i));
      if (!state.ok()) return send_error(res, state.status());
      states.push_back(*state);
    }
    absl::StatusOr<std::vector<JobStatus>> jobs =
        view_.jobs(std::size_t(limit->value_or(0)), states);
    if (!jobs.ok()) return send_error(res, jobs.status());
    v1::ListJobsResponse response;
    for (const JobStatus& job : *jobs) *response.add_jobs() = rpc::to_proto(job);
    send_message(res, response);
  };
  handlers["submitJob"] = [this](const httplib::Request& req, httplib::Response& res) {
    v1::SubmitJobRequest request;
    google::protobuf::util::JsonParseOptions options;
    options.ignore_unknown_fields = false;
    auto parsed = google::protobuf::util::JsonStringToMessage(req.body, &request, options);
    if (!parsed.ok()) {
      return send_error(
          res, absl::InvalidArgumentError(absl::StrCat("request body is not a SubmitJobRequest: ",
                                                       parsed.message().as_string())));
    }
    absl::StatusOr<JobStatus> job = farm_.submit(request.spec(), request.client_token());
    if (!job.ok()) return send_error(res, job.status());
    v1::SubmitJobResponse response;
    *response.mutable_job() = rpc::to_proto(*job);
    send_message(res, response);
  };
  handlers["getJob"] = [this](const httplib::Request& req, httplib::Response& res) {
    absl::StatusOr<JobStatus> job = view_.job(req.matches[1]);
    if (!job.ok()) return send_error(res, job.status());
    send_message(res, rpc::to_proto(*job));
  };
  handlers["cancelJob"] = [this](const httplib::Request& req, httplib::Response& res) {
    absl::StatusOr<JobStatus> job = farm_.cancel(req.matches[1]);
    if (!job.ok()) return send_error(res, job.status());
    send_message(res, rpc::to_proto(*job));
  };
  handlers["watchJob"] = [this](const httplib::Request& req, httplib::Response& res) {
    const std::string job_id = req.matches[1];
    // An unknown job is an ordinary 404, not an empty stream.
    if (absl::StatusOr<JobStatus> job = view_.job(job_id); !job.ok())
      return send_error(res, job.status());
    if (streams_.fetch_add(1) >= kMaxStreams) {
      streams_.fetch_sub(1);
      return send_error(res, absl::ResourceExhaustedError(absl::StrCat(
                                 "at most ", kMaxStreams, " event streams at once; try later")));
    }
    res.set_header("Cache-Control", "no-store");
    res.set_chunked_content_provider(
        "text/event-stream",
        [this, job_id](std::size_t, httplib::DataSink& sink) {
          absl::Status status = rpc::follow_job(
              view_, job_id, [this, &sink] { return stopping_.load() || !sink.is_writable(); },
              [&sink](const v1::JobInfo& info) {
                const std::string event = absl::StrCat("event: job\ndata: ", to_json(info), "\n\n");
                return sink.write(event.data(), event.size());
              });
          if (!status.ok()) {
            v1::ApiError error;
            error.set_code(absl::StatusCodeToString(status.code()));
            error.set_message(std::string(status.message()));
            const std::string event = absl::StrCat("event: error\ndata: ", to_json(error), "\n\n");
            sink.write(event.data(), event.size());
          }
          sink.done();
          return true;
        },
        [this](bool) { streams_.fetch_sub(1); });
  };
  handlers["getPreview"] = [this](const httplib::Request& req, httplib::Response& res) {
    absl::StatusOr<std::optional<double>> exposure = query_number(req, "exposure");
    if (!exposure.ok()) return send_error(res, exposure.status());
    if (exposure->has_value() && std::abs(**exposure) > 64) {
      return send_error(res, absl::InvalidArgumentError("query parameter exposure is not in "
                                                        "-64..64 stops"));
    }
    absl::StatusOr<std::string> png =
        view_.preview_png(req.matches[1], float(exposure->value_or(0)));
    if (!png.ok()) return send_error(res, png.status());
    res.set_header("Cache-Control", "no-store");
    res.set_content(*std::move(png), "image/png");
  };
  handlers["getTiles"] = [this](const httplib::Request& req, httplib::Response& res) {
    absl::StatusOr<TileMapStatus> map = view_.tile_map(req.matches[1]);
    if (!map.ok()) return send_error(res, map.status());
    v1::TileMap response;
    response.set_width(std::uint32_t(map->width));
    response.set_height(std::uint32_t(map->height));
    response.set_tile_size(std::uint32_t(map->tile_size));
    response.set_tiles_x(std::uint32_t(map->tiles_x));
    response.set_tiles_y(std::uint32_t(map->tiles_y));
    response.set_states(map->states);
    send_message(res, response);
  };
  handlers["getConvergence"] = [this](const httplib::Request& req, httplib::Response& res) {
    absl::StatusOr<std::vector<ConvergencePoint>> points = view_.convergence(req.matches[1]);
    if (!points.ok()) return send_error(res, points.status());
    v1::Convergence response;
    for (const ConvergencePoint& p : *points) {
      v1::ConvergencePoint* out = response.add_points();
      out->set_seconds(p.seconds);
      out->set_samples(p.samples);
      out->set_relative_error(p.relative_error);
    }
    send_message(res, response);
  };
  handlers["listResults"] = [this](const httplib::Request& req, httplib::Response& res) {
    absl::StatusOr<std::vector<OutputFile>> files = view_.result_files(req.matches[1], {});
    if (!files.ok()) return send_error(res, files.status());
    v1::ListResultsResponse response;
    for (const OutputFile& file : *files) {
      v1::ResultFile* out = response.add_files();
      out->set_kind(static_cast<v1::OutputKind>(static_cast<int>(file.kind)));
      out->set_file_name(file.file_name);
      std::error_code ec;
      const std::uintmax_t size = std::filesystem::file_size(file.path, ec);
      if (ec) {
        return send_error(
            res, absl::DataLossError(absl::StrCat("output ", file.file_name, " is missing")));
      }
      out->set_bytes(size);
    }
    send_message(res, response);
  };
  handlers["getResult"] = [this](const httplib::Request& req, httplib::Response& res) {
    const std::string job_id = req.matches[1], name = req.matches[2];
    absl::StatusOr<std::vector<OutputFile>> files = view_.result_files(job_id, {});
    if (!files.ok()) return send_error(res, files.status());
    auto file = std::find_if(files->begin(), files->end(),
                             [&](const OutputFile& f) { return f.file_name == name; });
    if (file == files->end()) {
      return send_error(
          res, absl::NotFoundError(absl::StrCat("job ", job_id, " has no output named ", name)));
    }
    std::error_code ec;
    const std::uintmax_t size = std::filesystem::file_size(file->path, ec);
    auto in = std::make_shared<std::ifstream>(file->path, std::ios::binary);
    if (ec || !*in) {
      return send_error(res, absl::DataLossError(absl::StrCat("output ", name, " is missing")));
    }
    res.set_header("Content-Disposition", absl::StrCat("attachment; filename=\"", name, "\""));
    res.set_content_provider(std::size_t(size), content_type_of(file->path),
                             [in](std::size_t offset, std::size_t length, httplib::DataSink& sink) {
                               std::string buffer(
                                   std::min<std::size_t>(length, std::size_t{1} << 20), '\0');
                               in->seekg(std::streamoff(offset));
                               in->read(buffer.data(), std::streamsize(buffer.size()));
                               if (in->gcount() <= 0) return false;
                               return sink.write(buffer.data(), std::size_t(in->gcount()));
                             });
  };
  handlers["listWorkers"] = [this](const httplib::Request&, httplib::Response& res) {
    absl::StatusOr<std::vector<WorkerStatus>> workers = view_.workers();
    if (!workers.ok()) return send_error(res, workers.status());
    v1::ListWorkersResponse response;
    for (const WorkerStatus& w : *workers) *response.add_workers() = rpc::to_proto(w);
    send_message(res, response);
  };
  handlers["hasBundle"] = [this](const httplib::Request& req, httplib::Response& res) {
    if (!base::is_sha256_hex(req.matches[1].str())) {
      return send_error(res, absl::InvalidArgumentError(
                                 absl::StrCat("bundle hash '", req.matches[1].str(),
                                              "': want 64 lower case hex digits (SHA-256)")));
    }
    v1::HasBundleResponse response;
    response.set_present(view_.has_bundle(req.matches[1]));
    send_message(res, response);
  };
  handlers["uploadBundle"] = [this](const httplib::Request& req, httplib::Response& res) {
    if (req.body.empty()) {
      return send_error(res, absl::InvalidArgumentError("the request body (the bundle) is empty"));
    }
    absl::StatusOr<std::string> hash = farm_.upload_bundle("", req.body);
    if (!hash.ok()) return send_error(res, hash.status());
    v1::UploadBundleResponse response;
    response.set_bundle_hash(*hash);
    send_message(res, response);
  };
  handlers["metrics"] = [this](const httplib::Request&, httplib::Response& res) {
    absl::StatusOr<std::string> text = view_.metrics_text();
    if (!text.ok()) return send_error(res, text.status());
    res.set_content(*std::move(text), "text/plain; version=0.0.4; charset=utf-8");
  };
  handlers["openapi"] = [](const httplib::Request&, httplib::Response& res) {
    res.set_content(openapi_document().dump(2), "application/json");
  };

  for (const Route& route : api_routes()) {
    auto it = handlers.find(route.id);
    PRISM_CHECK(it != handlers.end());
    Handler handler = [authorised, handle = it->second, open = !route.authenticated](
                          const httplib::Request& req, httplib::Response& res) {
      if (open || authorised(req, res)) handle(req, res);
    };
    const std::string pattern = path_regex(route.path);
    // A body is read through a content reader: cpp-httplib's own reading answers a body over
    // 8 KiB sent as application/x-www-form-urlencoded (curl's default for --data-binary, as in
    // the README's upload) with an empty 413, whatever the payload limit, and parses it as a
    // query. Read here, it is the bytes as sent, up to the bundle limit.
    auto with_body = [max = farm_.options().max_bundle_bytes, authorised,
                      open = !route.authenticated](Handler inner) {
      return [inner, max, authorised, open](const httplib::Request& req, httplib::Response& res,
                                            const httplib::ContentReader& reader) {
        // The token first: a client without one learns nothing of the limits below.
        if (!open && !authorised(req, res)) return;
        // A Content-Length over the limit is refused before reading: cpp-httplib would not read
        // it (payload_max_length), and the handler saw an empty body ("the bundle is empty").
        std::uint64_t declared = 0;
        if (req.has_header("Content-Length") &&
            absl::SimpleAtoi(req.get_header_value("Content-Length"), &declared) && declared > max) {
          return send_error(res, permanent_refusal(absl::ResourceExhaustedError(absl::StrCat(
                                     "the request body (", declared, " bytes) is over ", max,
                                     " bytes, the coordinator's --max-bundle-bytes"))));
        }
        std::string body;
        bool too_large = false;
        reader([&](const char* data, std::size_t n) {
          if (body.size() + n > max) {
            too_large = true;
            return false;
          }
          body.append(data, n);
          return true;
        });
        if (too_large) {
          return send_error(res, permanent_refusal(absl::ResourceExhaustedError(absl::StrCat(
                                     "the request body is over ", max,
                                     " bytes, the coordinator's --max-bundle-bytes"))));
        }
        httplib::Request with = req;
        with.body = std::move(body);
        inner(with, res);
      };
    };
    if (route.method == "get") {
      server_->Get(pattern, handler);
    } else if (route.method == "post" && route.request == nullptr && !route.binary_request) {
      // A POST without a body (`curl -X POST URL` sends no Content-Length, which cpp-httplib
      // refuses when it reads a body): a content-reader handler is dispatched before any read.
      server_->Post(pattern, [handler](const httplib::Request& req, httplib::Response& res,
                                       const httplib::ContentReader&) { handler(req, res); });
    } else if (route.method == "post") {
      server_->Post(pattern, with_body(handler));
    } else {
      PRISM_CHECK(route.method == "put");
      server_->Put(pattern, with_body(handler));
    }
  }
  // The dashboard: static files, no token (the page asks for it and sends it to the API).
  server_->Get("/", [](const httplib::Request&, httplib::Response& res) {
    res.set_redirect("/dashboard/");
  });
  server_->Get("/dashboard", [](const httplib::Request&, httplib::Response& res) {
    res.set_redirect("/dashboard/");
  });
  for (const DashboardAsset& asset : dashboard_assets()) {
    const std::string path =
        asset.name == "index.html" ? "/dashboard/" : "/dashboard/" + std::string(asset.name);
    server_->Get(path_regex(path), [asset](const httplib::Request&, httplib::Response& res) {
      res.set_header("Cache-Control", "no-cache");
      res.set_content(std::string(asset.content), std::string(asset.content_type));
    });
  }
  // Anything else: a path that a route has under other methods is a JSON 405 with the Allow
  // header (RFC 9110 15.5.6); any other a JSON 404 naming what was asked for.
  struct KnownRoute {
    std::regex pattern;
    std::string method;
    bool authenticated = true;
  };
  std::vector<KnownRoute> known;
  for (const Route& route : api_routes()) {
    known.push_back({std::regex(path_regex(route.path)), absl::AsciiStrToUpper(route.method),
                     route.authenticated});
  }
  Handler unknown = [known = std::move(known), authorised](const httplib::Request& req,
                                                           httplib::Response& res) {
    std::vector<std::string> allowed;
    bool authenticated = false;
    for (const KnownRoute& route : known) {
      if (!std::regex_match(req.path, route.pattern)) continue;
      authenticated |= route.authenticated;
      if (std::find(allowed.begin(), allowed.end(), route.method) == allowed.end()) {
        allowed.push_back(route.method);
      }
    }
    // The methods of a path that needs the token are told only to a client that has it.
    if (!allowed.empty() && authenticated && !authorised(req, res)) return;
    if (allowed.empty()) {
      return send_error(res,
                        absl::NotFoundError(absl::StrCat("no route ", req.method, " ", req.path,
                                                         " (see /api/v1/openapi.json)")));
    }
    const std::string allow = absl::StrJoin(allowed, ", ");
    v1::ApiError error;
    error.set_code("METHOD_NOT_ALLOWED");
    error.set_message(absl::StrCat(req.path, " takes ", allow, ", not ", req.method,
                                   " (see /api/v1/openapi.json)"));
    res.status = 405;
    res.set_header("Allow", allow);
    res.set_content(to_json(error), "application/json");
  };
  // Through a content reader, which nothing reads: cpp-httplib's own reading answers a body
  // without a Content-Length (curl -X PUT URL) with an empty 400 before any handler runs.
  auto unknown_with_body = [unknown](const httplib::Request& req, httplib::Response& res,
                                     const httplib::ContentReader&) { unknown(req, res); };
  server_->Get(".*", unknown);
  server_->Post(".*", unknown_with_body);
  server_->Put(".*", unknown_with_body);
  server_->Delete(".*", unknown_with_body);
  server_->Patch(".*", unknown_with_body);
  server_->set_exception_handler(
      [this](const httplib::Request& req, httplib::Response& res, std::exception_ptr ep) {
        std::string what = "unknown exception";
        try {
          std::rethrow_exception(ep);
        } catch (const std::exception& e) {
          what = e.what();
        } catch (...) {
        }
        logger_->error("HTTP {} {}: {}", req.method, req.path, what);
        send_error(res, absl::InternalError(absl::StrCat("internal error: ", what)));
      });
  server_->set_logger([this](const httplib::Request& req, const httplib::Response& res) {
    logger_->debug("HTTP {} {} {} from {}", req.method, req.path, res.status, req.remote_addr);
  });
}

}  // namespace prism::coordinator::http
