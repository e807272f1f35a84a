// The coordinator's HTTP/JSON API and Prometheus /metrics on one listener (`prism-coordinator
// --http-listen ADDR`; off by default). A thin adapter like the gRPC services: each route of
// api_routes.h checks the API token (`Authorization: Bearer <token>`, the same token as gRPC),
// converts the request, calls the FarmCoordinator (every read through its read-only FarmView,
// farm_view.h) and writes the reply as the protobuf message's JSON; errors are an ApiError body
// with the status mapped to HTTP. TLS with the coordinator's certificate and key when it has
// them.
//
// Built on cpp-httplib (Debian's libcpp-httplib-dev, compiled with OpenSSL): a maintained
// library in Debian, a thread pool per server, chunked responses for the event stream and file
// downloads, and TLS from the same PEM files gRPC uses. The listener runs its own thread pool
// (kThreads): an event stream holds one thread while it is open, and a bounded number of streams
// (kMaxStreams) keeps the rest of the API answering.
#pragma once

#include <spdlog/spdlog.h>

#include <atomic>
#include <memory>
#include <string>
#include <thread>

#include "absl/status/statusor.h"
#include "coordinator/farm_coordinator.h"
#include "services/rpc/credentials.h"

namespace httplib {
class Server;
}

namespace prism::coordinator::http {

struct HttpConfig {
  std::string listen = "127.0.0.1:0";  // host:port; port 0 picks a free port
  std::string api_token;               // empty: no authentication (local use, tests)
  prism::rpc::ServerTls tls;           // both paths set: HTTPS
};

class HttpApi {
 public:
  // cpp-httplib gives each connection a thread until it sends a request or its 5 s read
  // timeout ends: with 16, sixteen idle connections (before any authentication) held up the API,
  // /metrics and the dashboard. 64 leave room for many clients, scrapes and idle keep-alives.
  static constexpr int kThreads = 64;
  static constexpr int kMaxStreams = 8;

  // UNAVAILABLE when the address cannot be bound; INVALID_ARGUMENT for a malformed address or
  // TLS files that do not load.
  static absl::StatusOr<std::unique_ptr<HttpApi>> start(FarmCoordinator& farm,
                                                        const HttpConfig& config,
                                                        std::shared_ptr<spdlog::logger> logger);
  ~HttpApi();
  HttpApi(const HttpApi&) = delete;
  HttpApi& operator=(const HttpApi&) = delete;

  int port() const { return port_; }
  // Stops listening; open event streams end within one watch interval.
  void shutdown();

 private:
  HttpApi(FarmCoordinator& farm, HttpConfig config, std::shared_ptr<spdlog::logger> logger);
  void install_routes();

  FarmCoordinator& farm_;  // submissions, cancels, bundle uploads
  FarmView& view_;         // everything the API reads
  const HttpConfig config_;
  std::shared_ptr<spdlog::logger> logger_;
  std::unique_ptr<httplib::Server> server_;
  std::thread thread_;
  int port_ = 0;
  std::atomic<bool> stopping_{false};
  std::atomic<int> streams_{0};
};

}  // namespace prism::coordinator::http
