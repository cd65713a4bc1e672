// unix:PATH and tcp:HOST:PORT: probe stream client with reconnect and interrupt.
#include <arpa/inet.h>
#include <fcntl.h>
#include <netdb.h>
#include <netinet/in.h>
#include <poll.h>
#include <sys/socket.h>
#include <sys/un.h>
#include <unistd.h>

#include <cerrno>
#include <cstring>
#include <deque>
#include <vector>

#include "acquire/internal/sources.h"
#include "acquire/internal/stream_decoder.h"
#include "acquire/internal/waker.h"

namespace sonomesh::acquire::internal {
namespace {

using Clock = std::chrono::steady_clock;
using std::chrono::milliseconds;

constexpr milliseconds kFirstBackoff{50};
constexpr milliseconds kMaxBackoff{500};
constexpr std::size_t kReadChunk = 1 << 20;

AcquireError os_error(AcquireError::Code code, int err, std::string what) {
  return AcquireError{code, err, what + ": " + std::strerror(err), {}, 0};
}

struct Endpoint {
  bool is_unix = true;
  std::string path;  // unix
  std::string host;  // tcp
  std::string port;  // tcp
  std::string uri;
};

class SocketSource final : public Source {
 public:
  SocketSource(Endpoint endpoint, const SourceOptions& options)
      : endpoint_(std::move(endpoint)), options_(options), decoder_(options), buffer_(kReadChunk) {}
  ~SocketSource() override { close_fd(); }

  tl::expected<void, AcquireError> connect_now(milliseconds timeout) {
    auto fd = connect_once(Clock::now() + timeout);
    if (!fd) return tl::make_unexpected(fd.error());
    fd_ = *fd;
    return {};
  }

  tl::expected<RawVolume, AcquireError> next(milliseconds timeout) override {
    const auto deadline = Clock::now() + timeout;
    for (;;) {
      if (!ready_.empty()) {
        NextResult r = std::move(ready_.front());
        ready_.pop_front();
        return r;
      }
      if (finished_) {
        return tl::make_unexpected(
            AcquireError{AcquireError::Code::EndOfStream, 0, "stream ended", {}, 0});
      }
      if (auto r = decoder_.next()) {
        if (!*r && r->error().code == AcquireError::Code::EndOfStream) {
          finished_ = true;
          close_fd();
        }
        return std::move(*r);
      }
      if (fd_ < 0) {
        const auto now = Clock::now();
        if (now >= next_attempt_) {
          auto fd = connect_once(std::min(deadline, now + options_.connect_timeout));
          if (fd) {
            fd_ = *fd;
            backoff_ = kFirstBackoff;
            continue;
          }
          next_attempt_ = Clock::now() + backoff_;
          backoff_ = std::min(backoff_ * 2, kMaxBackoff);
        }
        if (Clock::now() >= deadline || waker_.sleep_until(std::min(deadline, next_attempt_))) {
          return timeout_error();
        }
        continue;
      }
      pollfd fds[2] = {{fd_, POLLIN, 0}, {waker_.fd(), POLLIN, 0}};
      const int n = ::poll(fds, 2, Waker::poll_ms(deadline));
      if (n < 0 && errno != EINTR) {
        return tl::make_unexpected(os_error(AcquireError::Code::IoError, errno, "poll"));
      }
      if (n > 0 && (fds[1].revents & POLLIN)) {
        waker_.drain();
        return timeout_error();
      }
      if (n > 0 && fds[0].revents != 0) {
        receive();
        continue;
      }
      if (Clock::now() >= deadline) return timeout_error();
    }
  }

  std::string describe() const override { return endpoint_.uri; }
  bool live() const override { return true; }
  void interrupt() override { waker_.wake(); }

 private:
  static tl::unexpected<AcquireError> timeout_error() {
    return tl::make_unexpected(AcquireError{AcquireError::Code::Timeout, 0, "no volume", {}, 0});
  }

  void close_fd() {
    if (fd_ >= 0) ::close(fd_);
    fd_ = -1;
  }

  // Reads what is there (bounded, so a fast sender cannot starve the caller) into the decoder.
  void receive() {
    for (int round = 0; round < 16; ++round) {
      const ssize_t n = ::recv(fd_, buffer_.data(), buffer_.size(), 0);
      if (n > 0) {
        decoder_.feed(buffer_.data(), static_cast<std::size_t>(n));
        if (static_cast<std::size_t>(n) < buffer_.size()) return;
        continue;
      }
      if (n < 0 && (errno == EAGAIN || errno == EWOULDBLOCK || errno == EINTR)) return;
      link_down(n == 0 ? std::string("closed by the probe") : std::string(std::strerror(errno)),
                n == 0 ? 0 : errno);
      return;
    }
  }

  void link_down(const std::string& why, int err) {
    close_fd();
    decoder_.end_of_input();
    while (auto r = decoder_.next()) ready_.push_back(std::move(*r));
    if (!decoder_.end_of_stream_seen()) {
      ready_.push_back(tl::make_unexpected(
          AcquireError{AcquireError::Code::Disconnected, err, endpoint_.uri + ": " + why, {}, 0}));
    }
    backoff_ = kFirstBackoff;
    next_attempt_ = Clock::now() + backoff_;
    backoff_ = std::min(backoff_ * 2, kMaxBackoff);
  }

  // Non-blocking connect, waiting for completion until `deadline` (or an interrupt).
  tl::expected<int, AcquireError> finish_connect(int fd, const sockaddr* addr, socklen_t len,
                                                 Clock::time_point deadline) {
    if (::connect(fd, addr, len) == 0) return fd;
    if (errno != EINPROGRESS && errno != EAGAIN) {
      const int err = errno;
      ::close(fd);
      const auto code = (err == ENOENT || err == ECONNREFUSED) ? AcquireError::Code::NotFound
                                                               : AcquireError::Code::IoError;
      return tl::make_unexpected(os_error(code, err, "connect " + endpoint_.uri));
    }
    pollfd fds[2] = {{fd, POLLOUT, 0}, {waker_.fd(), POLLIN, 0}};
    const int n = ::poll(fds, 2, Waker::poll_ms(deadline));
    if (n <= 0 || (fds[1].revents & POLLIN)) {
      ::close(fd);
      return tl::make_unexpected(AcquireError{AcquireError::Code::Timeout, ETIMEDOUT,
                                              "connect " + endpoint_.uri + ": timed out", {}, 0});
    }
    int err = 0;
    socklen_t err_len = sizeof err;
    ::getsockopt(fd, SOL_SOCKET, SO_ERROR, &err, &err_len);
    if (err != 0) {
      ::close(fd);
      const auto code = err == ECONNREFUSED ? AcquireError::Code::NotFound
                                            : AcquireError::Code::IoError;
      return tl::make_unexpected(os_error(code, err, "connect " + endpoint_.uri));
    }
    return fd;
  }

  tl::expected<int, AcquireError> connect_once(Clock::time_point deadline) {
    if (endpoint_.is_unix) {
      sockaddr_un addr{};
      addr.sun_family = AF_UNIX;
      std::memcpy(addr.sun_path, endpoint_.path.data(), endpoint_.path.size());
      const int fd = ::socket(AF_UNIX, SOCK_STREAM | SOCK_NONBLOCK | SOCK_CLOEXEC, 0);
      if (fd < 0) return tl::make_unexpected(os_error(AcquireError::Code::IoError, errno, "socket"));
      return finish_connect(fd, reinterpret_cast<const sockaddr*>(&addr), sizeof addr, deadline);
    }
    addrinfo hints{};
    hints.ai_family = AF_UNSPEC;
    hints.ai_socktype = SOCK_STREAM;
    addrinfo* list = nullptr;
    const int rc = ::getaddrinfo(endpoint_.host.c_str(), endpoint_.port.c_str(), &hints, &list);
    if (rc != 0) {
      return tl::make_unexpected(AcquireError{AcquireError::Code::NotFound, 0,
                                              endpoint_.uri + ": " + ::gai_strerror(rc), {}, 0});
    }
    tl::expected<int, AcquireError> result = tl::make_unexpected(
        AcquireError{AcquireError::Code::NotFound, 0, endpoint_.uri + ": no address", {}, 0});
    for (addrinfo* ai = list; ai != nullptr; ai = ai->ai_next) {
      const int fd = ::socket(ai->ai_family, ai->ai_socktype | SOCK_NONBLOCK | SOCK_CLOEXEC,
                              ai->ai_protocol);
      if (fd < 0) continue;
      result = finish_connect(fd, ai->ai_addr, ai->ai_addrlen, deadline);
      if (result) break;
    }
    ::freeaddrinfo(list);
    return result;
  }

  Endpoint endpoint_;
  SourceOptions options_;
  StreamDecoder decoder_;
  std::vector<std::uint8_t> buffer_;
  std::deque<NextResult> ready_;
  Waker waker_;
  int fd_ = -1;
  bool finished_ = false;
  milliseconds backoff_ = kFirstBackoff;
  Clock::time_point next_attempt_{};
};

tl::expected<std::unique_ptr<Source>, AcquireError> open_socket(Endpoint endpoint,
                                                                const SourceOptions& options) {
  auto source = std::make_unique<SocketSource>(std::move(endpoint), options);
  if (auto r = source->connect_now(options.connect_timeout); !r) {
    return tl::make_unexpected(r.error());
  }
  return source;
}

}  // namespace

tl::expected<std::unique_ptr<Source>, AcquireError> open_unix_source(const std::string& spec,
                                                                     const SourceOptions& options) {
  if (spec.empty() || spec.size() >= sizeof(sockaddr_un{}.sun_path)) {
    return tl::make_unexpected(AcquireError{
        AcquireError::Code::InvalidArgument, 0,
        "unix:" + spec + ": socket path must be 1.." +
            std::to_string(sizeof(sockaddr_un{}.sun_path) - 1) + " characters",
        {}, 0});
  }
  return open_socket(Endpoint{true, spec, "", "", "unix:" + spec}, options);
}

tl::expected<std::unique_ptr<Source>, AcquireError> open_tcp_source(const std::string& spec,
                                                                    const SourceOptions& options) {
  const auto colon = spec.rfind(':');
  if (colon == std::string::npos || colon == 0 || colon + 1 == spec.size()) {
    return tl::make_unexpected(AcquireError{AcquireError::Code::InvalidArgument, 0,
                                            "tcp:" + spec + ": expected tcp:HOST:PORT", {}, 0});
  }
  std::string host = spec.substr(0, colon);
  if (host.size() > 2 && host.front() == '[' && host.back() == ']') {
    host = host.substr(1, host.size() - 2);  // [::1]
  }
  return open_socket(Endpoint{false, "", host, spec.substr(colon + 1), "tcp:" + spec}, options);
}

}  // namespace sonomesh::acquire::internal
