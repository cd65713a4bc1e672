#pragma once
// Headless Chromium driven over its DevTools protocol on a pipe (--remote-debugging-pipe:
// commands on the child's fd 3, answers and events on its fd 4, each message JSON ended by a NUL
// byte), so a test can load a page, read values out of it and take screenshots without a
// WebSocket client or a Node.js driver.
#include <poll.h>
#include <unistd.h>

#include <memory>
#include <nlohmann/json.hpp>
#include <optional>
#include <string>
#include <vector>

#include "child_process.h"

namespace sonomesh::testing {

class Chromium {
 public:
  static constexpr const char* kBinary = "/usr/bin/chromium";
  static bool available() { return ::access(kBinary, X_OK) == 0; }

  explicit Chromium(const fs::path& scratch) {
    int to_child[2], from_child[2];
    if (::pipe2(to_child, O_CLOEXEC) != 0 || ::pipe2(from_child, O_CLOEXEC) != 0) return;
    // Above the child's 3 and 4, so each dup2 really copies (and clears close-on-exec).
    for (int* fd : {&to_child[0], &to_child[1], &from_child[0], &from_child[1]}) {
      if (*fd <= 4) {
        const int moved = ::fcntl(*fd, F_DUPFD_CLOEXEC, 10);
        ::close(*fd);
        *fd = moved;
      }
    }
    // Flags: swiftshader renders WebGL without a GPU; no background networking (this machine's
    // network is closed and each refused connection costs time); a fresh profile.
    std::vector<std::string> argv = {kBinary,
                                     "--headless",
                                     "--no-sandbox",
                                     "--enable-unsafe-swiftshader",
                                     "--use-angle=swiftshader",
                                     "--disable-background-networking",
                                     "--disable-component-update",
                                     "--disable-sync",
                                     "--disable-quic",
                                     "--no-first-run",
                                     "--window-size=1200,900",
                                     "--user-data-dir=" + (scratch / "chromium-profile").string(),
                                     "--remote-debugging-pipe",
                                     "about:blank"};
    process_ = std::make_unique<Child>(
        argv, scratch / "chromium", std::vector<std::string>{},
        std::vector<std::pair<int, int>>{{3, to_child[0]}, {4, from_child[1]}});
    ::close(to_child[0]);
    ::close(from_child[1]);
    write_fd_ = to_child[1];
    read_fd_ = from_child[0];
  }
  ~Chromium() {
    if (write_fd_ >= 0) {
      call("Browser.close", nlohmann::json::object(), {}, 5s);
      ::close(write_fd_);
    }
    if (read_fd_ >= 0) ::close(read_fd_);
    if (process_) process_->wait(5s);
  }

  // Sends a command and waits for its answer; nothing on timeout or a protocol error.
  std::optional<nlohmann::json> call(const std::string& method, nlohmann::json params,
                                     const std::string& session = {},
                                     std::chrono::milliseconds timeout = 30s) {
    const int id = ++last_id_;
    nlohmann::json message = {{"id", id}, {"method", method}, {"params", std::move(params)}};
    if (!session.empty()) message["sessionId"] = session;
    std::string text = message.dump();
    text.push_back('\0');
    if (::write(write_fd_, text.data(), text.size()) != static_cast<ssize_t>(text.size())) {
      return std::nullopt;
    }
    const auto deadline = Clock::now() + timeout;
    while (Clock::now() < deadline) {
      for (auto& m : drain(deadline)) {
        if (m.value("id", -1) != id) continue;  // events and other answers
        if (m.contains("error")) {
          last_error_ = m["error"].dump();
          return std::nullopt;
        }
        return m["result"];
      }
    }
    last_error_ = "timeout waiting for " + method;
    return std::nullopt;
  }

  // A new page attached in flattened mode; returns its session id.
  std::optional<std::string> open_page(const std::string& url) {
    auto target = call("Target.createTarget", {{"url", "about:blank"}});
    if (!target) return std::nullopt;
    auto attached =
        call("Target.attachToTarget", {{"targetId", (*target)["targetId"]}, {"flatten", true}});
    if (!attached) return std::nullopt;
    const std::string session = (*attached)["sessionId"];
    if (!call("Page.enable", nlohmann::json::object(), session)) return std::nullopt;
    if (!call("Page.navigate", {{"url", url}}, session)) return std::nullopt;
    return session;
  }

  // Evaluates a JavaScript expression in the page; its JSON value (returnByValue).
  std::optional<nlohmann::json> evaluate(const std::string& session, const std::string& expr) {
    auto r = call("Runtime.evaluate", {{"expression", expr}, {"returnByValue", true}}, session);
    if (!r || r->contains("exceptionDetails")) return std::nullopt;
    return (*r)["result"].value("value", nlohmann::json());
  }

  // The page as a PNG (bytes).
  std::optional<std::string> screenshot(const std::string& session) {
    auto r = call("Page.captureScreenshot", {{"format", "png"}}, session);
    if (!r) return std::nullopt;
    return base64_decode((*r)["data"].get<std::string>());
  }

  const std::string& last_error() const { return last_error_; }
  bool started() const { return process_ && process_->pid() > 0 && read_fd_ >= 0; }

  static std::string base64_decode(const std::string& in) {
    auto value = [](char c) -> int {
      if (c >= 'A' && c <= 'Z') return c - 'A';
      if (c >= 'a' && c <= 'z') return c - 'a' + 26;
      if (c >= '0' && c <= '9') return c - '0' + 52;
      if (c == '+') return 62;
      if (c == '/') return 63;
      return -1;
    };
    std::string out;
    unsigned bits = 0;
    int count = 0;
    for (char c : in) {
      const int v = value(c);
      if (v < 0) continue;  // padding, newlines
      bits = (bits << 6) | static_cast<unsigned>(v);
      count += 6;
      if (count >= 8) {
        count -= 8;
        out.push_back(static_cast<char>((bits >> count) & 0xff));
      }
    }
    return out;
  }

 private:
  // Complete messages that arrived before `deadline` (at least one poll).
  std::vector<nlohmann::json> drain(Clock::time_point deadline) {
    std::vector<nlohmann::json> out;
    const auto left =
        std::chrono::duration_cast<std::chrono::milliseconds>(deadline - Clock::now());
    pollfd p{read_fd_, POLLIN, 0};
    if (::poll(&p, 1, static_cast<int>(std::max<long>(1, std::min<long>(left.count(), 200)))) <=
        0) {
      return out;
    }
    char buf[65536];
    const ssize_t n = ::read(read_fd_, buf, sizeof buf);
    if (n <= 0) return out;
    buffer_.append(buf, static_cast<std::size_t>(n));
    for (std::size_t nul; (nul = buffer_.find('\0')) != std::string::npos;) {
      auto j = nlohmann::json::parse(buffer_.substr(0, nul), nullptr, false);
      buffer_.erase(0, nul + 1);
      if (!j.is_discarded()) out.push_back(std::move(j));
    }
    return out;
  }

  std::unique_ptr<Child> process_;
  int write_fd_ = -1, read_fd_ = -1;
  int last_id_ = 0;
  std::string buffer_;
  std::string last_error_;
};

}  // namespace sonomesh::testing
