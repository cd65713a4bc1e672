#pragma once
/// @file
/// @brief The daemon's HTTP status server (cpp-httplib): /healthz, /status, /metrics,
/// /latest.ply, POST /seed.

#include <array>
#include <filesystem>
#include <functional>
#include <memory>
#include <optional>
#include <string>
#include <thread>

#include "daemon/internal/run_stats.h"
#include "daemon/internal/web_routes.h"

namespace httplib {
class Server;
}

namespace sonomesh::daemon {

struct HttpAddress {
  std::string host = "127.0.0.1";
  int port = 0;  // 0: any free port (the bound port is reported by start())
};

/// Parses "HOST:PORT", "[V6]:PORT" or ":PORT"/"PORT" (host 127.0.0.1). Nothing if malformed.
std::optional<HttpAddress> parse_http_address(const std::string& text);
/// True for 127.0.0.0/8, ::1 and "localhost".
bool is_loopback_host(const std::string& host);

/// Parses a seed: "x,y,z" (mm) or JSON {"seed_mm":[x,y,z]} or [x,y,z]. Nothing if malformed or
/// not finite.
std::optional<std::array<float, 3>> parse_seed_text(const std::string& text);

class HttpStatusServer {
 public:
  /// Called for POST /seed with the parsed seed; returns an error message to refuse it.
  using SeedHandler = std::function<std::optional<std::string>(const std::array<float, 3>&)>;

  HttpStatusServer(const RunStats& stats, std::filesystem::path latest_ply, SeedHandler on_seed);
  ~HttpStatusServer();
  HttpStatusServer(const HttpStatusServer&) = delete;
  HttpStatusServer& operator=(const HttpStatusServer&) = delete;

  /// web (issue 18): also serve the live page, /events and /slices (call before start()).
  void set_web(WebContext web) { web_ = std::move(web); }

  /// Binds and starts serving on a thread of its own. Returns the bound port.
  /// @throws std::runtime_error if the address cannot be bound.
  int start(const HttpAddress& address);
  /// Stops serving and joins the thread (idempotent).
  void stop();

 private:
  const RunStats& stats_;
  std::filesystem::path latest_ply_;
  SeedHandler on_seed_;
  std::optional<WebContext> web_;
  std::unique_ptr<httplib::Server> server_;
  std::thread thread_;
};

}  // namespace sonomesh::daemon
