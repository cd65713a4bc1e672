// connect_stream(): getaddrinfo / unix path, non-blocking connect, poll with the waker.
#include "acquire/internal/socket_connect.h"

#include <netdb.h>
#include <poll.h>
#include <sys/socket.h>
#include <sys/un.h>
#include <unistd.h>

#include <algorithm>
#include <cerrno>
#include <cstring>

namespace sonomesh::acquire::internal {
namespace {

using Clock = std::chrono::steady_clock;

AcquireError os_error(AcquireError::Code code, int err, const std::string& what) {
  return AcquireError{code, err, what + ": " + std::strerror(err), {}, 0};
}

tl::expected<int, AcquireError> finish_connect(int fd, const sockaddr* addr, socklen_t len,
                                               const std::string& uri, Clock::time_point deadline,
                                               Waker& waker) {
  if (::connect(fd, addr, len) == 0) return fd;
  if (errno != EINPROGRESS && errno != EAGAIN) {
    const int err = errno;
    ::close(fd);
    const auto code = (err == ENOENT || err == ECONNREFUSED) ? AcquireError::Code::NotFound
                                                             : AcquireError::Code::IoError;
    return tl::make_unexpected(os_error(code, err, "connect " + uri));
  }
  pollfd fds[2] = {{fd, POLLOUT, 0}, {waker.fd(), POLLIN, 0}};
  const int n = ::poll(fds, 2, Waker::poll_ms(deadline));
  if (n <= 0 || (fds[1].revents & POLLIN)) {
    ::close(fd);
    return tl::make_unexpected(AcquireError{
        AcquireError::Code::Timeout, ETIMEDOUT, "connect " + uri + ": timed out", {}, 0});
  }
  int err = 0;
  socklen_t err_len = sizeof err;
  ::getsockopt(fd, SOL_SOCKET, SO_ERROR, &err, &err_len);
  if (err != 0) {
    ::close(fd);
    const auto code =
        err == ECONNREFUSED ? AcquireError::Code::NotFound : AcquireError::Code::IoError;
    return tl::make_unexpected(os_error(code, err, "connect " + uri));
  }
  return fd;
}

tl::expected<int, AcquireError> connect_unix(const Endpoint& endpoint, Clock::time_point deadline,
                                             Waker& waker) {
  sockaddr_un addr{};
  addr.sun_family = AF_UNIX;
  std::memcpy(addr.sun_path, endpoint.path.data(),
              std::min(endpoint.path.size(), sizeof addr.sun_path - 1));
  const int fd = ::socket(AF_UNIX, SOCK_STREAM | SOCK_NONBLOCK | SOCK_CLOEXEC, 0);
  if (fd < 0) return tl::make_unexpected(os_error(AcquireError::Code::IoError, errno, "socket"));
  return finish_connect(fd, reinterpret_cast<const sockaddr*>(&addr), sizeof addr, endpoint.uri,
                        deadline, waker);
}

}  // namespace

std::optional<Endpoint> tcp_endpoint(const std::string& host_port, const std::string& uri) {
  const auto colon = host_port.rfind(':');
  if (colon == std::string::npos || colon == 0 || colon + 1 == host_port.size()) {
    return std::nullopt;
  }
  std::string host = host_port.substr(0, colon);
  if (host.size() > 2 && host.front() == '[' && host.back() == ']') {
    host = host.substr(1, host.size() - 2);  // [::1]
  }
  return Endpoint{false, "", host, host_port.substr(colon + 1), uri};
}

tl::expected<int, AcquireError> connect_stream(const Endpoint& endpoint, Clock::time_point deadline,
                                               Waker& waker) {
  if (endpoint.is_unix) return connect_unix(endpoint, deadline, waker);
  addrinfo hints{};
  hints.ai_family = AF_UNSPEC;
  hints.ai_socktype = SOCK_STREAM;
  addrinfo* list = nullptr;
  const int rc = ::getaddrinfo(endpoint.host.c_str(), endpoint.port.c_str(), &hints, &list);
  if (rc != 0) {
    return tl::make_unexpected(AcquireError{
        AcquireError::Code::NotFound, 0, endpoint.uri + ": " + ::gai_strerror(rc), {}, 0});
  }
  tl::expected<int, AcquireError> result = tl::make_unexpected(
      AcquireError{AcquireError::Code::NotFound, 0, endpoint.uri + ": no address", {}, 0});
  for (addrinfo* ai = list; ai != nullptr; ai = ai->ai_next) {
    const int fd =
        ::socket(ai->ai_family, ai->ai_socktype | SOCK_NONBLOCK | SOCK_CLOEXEC, ai->ai_protocol);
    if (fd < 0) continue;
    result = finish_connect(fd, ai->ai_addr, ai->ai_addrlen, endpoint.uri, deadline, waker);
    if (result) break;
  }
  ::freeaddrinfo(list);
  return result;
}

std::optional<int> reconnect_step(const Endpoint& endpoint, Backoff& backoff, Waker& waker,
                                  Clock::time_point deadline,
                                  std::chrono::milliseconds connect_timeout) {
  if (backoff.due()) {
    auto fd = connect_stream(endpoint, std::min(deadline, Clock::now() + connect_timeout), waker);
    if (fd) {
      backoff.succeeded();
      return *fd;
    }
    backoff.failed();
  }
  if (Clock::now() >= deadline || waker.sleep_until(std::min(deadline, backoff.next_attempt())))
    return std::nullopt;
  return -1;
}

SocketWait wait_readable(int fd, Waker& waker, Clock::time_point deadline) {
  for (;;) {
    pollfd fds[2] = {{fd, POLLIN, 0}, {waker.fd(), POLLIN, 0}};
    const int n = ::poll(fds, 2, Waker::poll_ms(deadline));
    if (n < 0 && errno != EINTR) return SocketWait::Failed;
    if (n > 0 && (fds[1].revents & POLLIN)) {
      waker.drain();
      return SocketWait::Timeout;
    }
    if (n > 0 && fds[0].revents != 0) return SocketWait::Readable;
    if (Clock::now() >= deadline) return SocketWait::Timeout;
  }
}

std::optional<LinkDown> receive_available(
    int fd, std::vector<std::uint8_t>& buffer, const char* peer,
    const std::function<bool(const std::uint8_t*, std::size_t)>& feed) {
  for (int round = 0; round < 16; ++round) {
    const ssize_t n = ::recv(fd, buffer.data(), buffer.size(), 0);
    if (n > 0) {
      if (!feed(buffer.data(), static_cast<std::size_t>(n))) return std::nullopt;
      if (static_cast<std::size_t>(n) < buffer.size()) return std::nullopt;
      continue;
    }
    if (n < 0 && (errno == EAGAIN || errno == EWOULDBLOCK || errno == EINTR)) return std::nullopt;
    if (n == 0) return LinkDown{std::string("closed by the ") + peer, 0};
    return LinkDown{std::strerror(errno), errno};
  }
  return std::nullopt;
}

}  // namespace sonomesh::acquire::internal
