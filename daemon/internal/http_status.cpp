#include "daemon/internal/http_status.h"

#include <arpa/inet.h>
#include <httplib.h>

#include <charconv>
#include <cmath>
#include <fstream>
#include <nlohmann/json.hpp>
#include <sstream>
#include <stdexcept>

namespace sonomesh::daemon {

std::optional<HttpAddress> parse_http_address(const std::string& text) {
  HttpAddress address;
  std::string port_text;
  if (!text.empty() && text.front() == '[') {
    const auto close = text.find(']');
    if (close == std::string::npos || close + 1 >= text.size() || text[close + 1] != ':') {
      return std::nullopt;
    }
    address.host = text.substr(1, close - 1);
    port_text = text.substr(close + 2);
  } else {
    const auto colon = text.rfind(':');
    if (colon == std::string::npos) {
      port_text = text;
    } else {
      if (text.find(':') != colon) return std::nullopt;  // bare IPv6 needs brackets
      if (colon > 0) address.host = text.substr(0, colon);
      port_text = text.substr(colon + 1);
    }
  }
  if (address.host.empty() || port_text.empty()) return std::nullopt;
  int port = -1;
  const auto [end, ec] =
      std::from_chars(port_text.data(), port_text.data() + port_text.size(), port);
  if (ec != std::errc() || end != port_text.data() + port_text.size() || port < 0 || port > 65535) {
    return std::nullopt;
  }
  address.port = port;
  return address;
}

bool is_loopback_host(const std::string& host) {
  if (host == "localhost") return true;
  in_addr v4{};
  if (inet_pton(AF_INET, host.c_str(), &v4) == 1) {
    return (ntohl(v4.s_addr) >> 24) == 127;
  }
  in6_addr v6{};
  if (inet_pton(AF_INET6, host.c_str(), &v6) == 1) {
    return IN6_IS_ADDR_LOOPBACK(&v6);
  }
  return false;
}

std::optional<std::array<float, 3>> parse_seed_text(const std::string& text) {
  std::array<float, 3> seed{};
  const auto first = text.find_first_not_of(" \t\r\n");
  if (first == std::string::npos) return std::nullopt;
  if (text[first] == '{' || text[first] == '[') {
    const auto j = nlohmann::json::parse(text, nullptr, false);
    if (j.is_discarded()) return std::nullopt;
    const nlohmann::json* arr = &j;
    if (j.is_object()) {
      if (!j.contains("seed_mm")) return std::nullopt;
      arr = &j["seed_mm"];
    }
    if (!arr->is_array() || arr->size() != 3) return std::nullopt;
    for (int i = 0; i < 3; ++i) {
      if (!(*arr)[i].is_number()) return std::nullopt;
      seed[i] = (*arr)[i].get<float>();
    }
  } else {
    std::string cleaned = text;
    for (char& c : cleaned) {
      if (c == ',') c = ' ';
    }
    std::istringstream in(cleaned);
    for (int i = 0; i < 3; ++i) {
      if (!(in >> seed[i])) return std::nullopt;
    }
    std::string rest;
    if (in >> rest) return std::nullopt;
  }
  for (float v : seed) {
    if (!std::isfinite(v)) return std::nullopt;
  }
  return seed;
}

HttpStatusServer::HttpStatusServer(const RunStats& stats, std::filesystem::path latest_ply,
                                   SeedHandler on_seed)
    : stats_(stats), latest_ply_(std::move(latest_ply)), on_seed_(std::move(on_seed)) {}

HttpStatusServer::~HttpStatusServer() { stop(); }

int HttpStatusServer::start(const HttpAddress& address) {
  server_ = std::make_unique<httplib::Server>();
  auto& s = *server_;
  // httplib's default also sets SO_REUSEPORT, which would let a second daemon bind the same port
  // silently and steal half the requests; SO_REUSEADDR alone allows quick restarts.
  s.set_socket_options([](socket_t sock) {
    int yes = 1;
    ::setsockopt(sock, SOL_SOCKET, SO_REUSEADDR, &yes, sizeof yes);
  });
  s.Get("/healthz", [](const httplib::Request&, httplib::Response& res) {
    res.set_content("{\"status\":\"ok\"}\n", "application/json");
  });
  s.Get("/status", [this](const httplib::Request&, httplib::Response& res) {
    res.set_content(stats_.status_json().dump(2) + "\n", "application/json");
  });
  s.Get("/metrics", [this](const httplib::Request&, httplib::Response& res) {
    res.set_content(stats_.prometheus_text(), "text/plain; version=0.0.4; charset=utf-8");
  });
  s.Get("/latest.ply", [this](const httplib::Request&, httplib::Response& res) {
    // latest.ply is replaced by rename(2): the stream opened here keeps reading one whole file.
    std::ifstream in(latest_ply_, std::ios::binary);
    if (!in) {
      res.status = 404;
      res.set_content("{\"error\":\"no mesh yet\"}\n", "application/json");
      return;
    }
    std::ostringstream bytes;
    bytes << in.rdbuf();
    res.set_content(bytes.str(), "application/octet-stream");
  });
  s.Post("/seed", [this](const httplib::Request& req, httplib::Response& res) {
    const auto seed = parse_seed_text(req.body);
    if (!seed) {
      res.status = 400;
      res.set_content(
          "{\"error\":\"body must be \\\"x,y,z\\\" or {\\\"seed_mm\\\":[x,y,z]} (mm)\"}\n",
          "application/json");
      return;
    }
    if (on_seed_) {
      if (auto err = on_seed_(*seed)) {
        res.status = 400;
        res.set_content(nlohmann::json{{"error", *err}}.dump() + "\n", "application/json");
        return;
      }
    }
    res.set_content(nlohmann::json{{"seed_mm", *seed}}.dump() + "\n", "application/json");
  });

  if (web_) add_web_routes(s, *web_);  // web: the live page, /events, /slices

  int port = address.port;
  if (port == 0) {
    port = s.bind_to_any_port(address.host);
    if (port <= 0) throw std::runtime_error("cannot bind HTTP to " + address.host + ":0");
  } else if (!s.bind_to_port(address.host, port)) {
    throw std::runtime_error("cannot bind HTTP to " + address.host + ":" + std::to_string(port) +
                             " (in use or not a local address)");
  }
  thread_ = std::thread([this] { server_->listen_after_bind(); });
  // stop() is a no-op until the server runs: wait for it, or a stop right after start would leave
  // the listening thread running forever.
  for (int i = 0; i < 5000 && !server_->is_running(); ++i) {
    std::this_thread::sleep_for(std::chrono::milliseconds(1));
  }
  return port;
}

void HttpStatusServer::stop() {
  if (server_) server_->stop();
  if (thread_.joinable()) thread_.join();
}

}  // namespace sonomesh::daemon
