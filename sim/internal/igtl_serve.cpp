#include "sim/internal/igtl_serve.h"

#include <netdb.h>
#include <netinet/in.h>
#include <netinet/tcp.h>
#include <poll.h>
#include <signal.h>
#include <sys/socket.h>
#include <unistd.h>

#include <algorithm>
#include <cerrno>
#include <chrono>
#include <cmath>
#include <cstring>
#include <iostream>
#include <stdexcept>
#include <vector>

#include "sim/internal/igtl_image.h"

namespace sonomesh::sim::internal {
namespace {

using Clock = std::chrono::steady_clock;

void log_line(const std::string& text) { std::cerr << "probe-sim: " + text + "\n" << std::flush; }

int listen_on(const std::string& address) {
  const auto colon = address.rfind(':');
  if (colon == std::string::npos || colon + 1 == address.size())
    throw std::invalid_argument("--igtl " + address + ": expected HOST:PORT");
  const std::string host = address.substr(0, colon), port = address.substr(colon + 1);
  addrinfo hints{};
  hints.ai_family = AF_UNSPEC;
  hints.ai_socktype = SOCK_STREAM;
  hints.ai_flags = AI_PASSIVE;
  addrinfo* list = nullptr;
  if (const int rc =
          ::getaddrinfo(host.empty() ? nullptr : host.c_str(), port.c_str(), &hints, &list);
      rc != 0)
    throw std::runtime_error("--igtl " + address + ": " + ::gai_strerror(rc));
  const int fd = ::socket(list->ai_family, SOCK_STREAM | SOCK_CLOEXEC, 0);
  const int one = 1;
  ::setsockopt(fd, SOL_SOCKET, SO_REUSEADDR, &one, sizeof one);
  const int rc = ::bind(fd, list->ai_addr, list->ai_addrlen);
  ::freeaddrinfo(list);
  if (rc != 0 || ::listen(fd, 8) != 0) {
    const std::string why = std::strerror(errno);
    ::close(fd);
    throw std::runtime_error("listen " + address + ": " + why);
  }
  return fd;
}

bool send_all(int fd, const std::vector<std::uint8_t>& bytes) {
  const std::uint8_t* data = bytes.data();
  std::size_t size = bytes.size();
  while (size > 0) {
    const ssize_t n = ::send(fd, data, size, MSG_NOSIGNAL);
    if (n < 0 && errno == EINTR) continue;
    if (n <= 0) return false;
    data += n;
    size -= static_cast<std::size_t>(n);
  }
  return true;
}

class Clients {
 public:
  explicit Clients(int listen_fd) : listen_fd_(listen_fd) {}
  ~Clients() {
    for (int fd : fds_) {
      ::shutdown(fd, SHUT_WR);
      ::close(fd);
    }
  }
  bool empty() const { return fds_.empty(); }

  /// Accepts, reads (and ignores) what clients send and notices hang-ups, until `until`.
  void service(Clock::time_point until) {
    for (;;) {
      std::vector<pollfd> polls{{listen_fd_, POLLIN, 0}};
      for (int fd : fds_) polls.push_back({fd, POLLIN, 0});
      const auto left =
          std::chrono::duration_cast<std::chrono::milliseconds>(until - Clock::now()).count();
      const int rc = ::poll(polls.data(), polls.size(),
                            static_cast<int>(std::clamp<long long>(left, 0, 1000)));
      if (rc < 0 && errno != EINTR)
        throw std::runtime_error(std::string("poll: ") + std::strerror(errno));
      if (rc > 0) {
        for (std::size_t p = polls.size(); p-- > 1;)
          if (polls[p].revents != 0 && !drain(polls[p].fd))
            drop(polls[p].fd, "client disconnected");
        if (polls[0].revents & POLLIN) accept_one();
      }
      if (Clock::now() >= until) return;
    }
  }

  /// Sends to every client; a failed send drops that client.
  void broadcast(const std::vector<std::uint8_t>& bytes) {
    for (std::size_t c = fds_.size(); c-- > 0;)
      if (!send_all(fds_[c], bytes)) drop(fds_[c], "client dropped (gone or not reading)");
  }

 private:
  void accept_one() {
    const int fd = ::accept4(listen_fd_, nullptr, nullptr, SOCK_CLOEXEC);
    if (fd < 0) return;
    const int one = 1;
    ::setsockopt(fd, IPPROTO_TCP, TCP_NODELAY, &one, sizeof one);
    const timeval stall{2, 0};  // a client that stops reading for 2 s is dropped
    ::setsockopt(fd, SOL_SOCKET, SO_SNDTIMEO, &stall, sizeof stall);
    fds_.push_back(fd);
    log_line("OpenIGTLink client connected (" + std::to_string(fds_.size()) + " now)");
  }
  // Reads what is there; false when the peer closed or failed.
  static bool drain(int fd) {
    std::uint8_t scratch[4096];
    const ssize_t n = ::recv(fd, scratch, sizeof scratch, MSG_DONTWAIT);
    return n > 0 || (n < 0 && (errno == EAGAIN || errno == EWOULDBLOCK || errno == EINTR));
  }
  void drop(int fd, const char* why) {
    ::close(fd);
    fds_.erase(std::find(fds_.begin(), fds_.end(), fd));
    log_line(std::string(why) + " (" + std::to_string(fds_.size()) + " left)");
  }

  int listen_fd_;
  std::vector<int> fds_;
};

}  // namespace

int run_igtl_serve(const IgtlServeOptions& options, const VolumeSupplier& next) {
  if (options.header_version != 1 && options.header_version != 2)
    throw std::invalid_argument("--igtl-header must be 1 or 2");
  if (!(options.rate_hz > 0)) throw std::invalid_argument("--rate must be > 0 with --igtl");
  ::signal(SIGPIPE, SIG_IGN);
  const int listen_fd = listen_on(options.address);
  log_line("OpenIGTLink server (IMAGE '" + options.device + "', header v" +
           std::to_string(options.header_version) + ") listening on " + options.address);
  Clients clients(listen_fd);
  std::uint64_t sequence = 0, paced = 0, sent = 0;
  Clock::time_point start{};
  while (options.count == 0 || sent < options.count) {
    if (clients.empty()) {  // pacing restarts with the next client
      clients.service(Clock::now() + std::chrono::milliseconds(200));
      start = Clock::now();
      paced = 0;
      continue;
    }
    const auto due = start + std::chrono::nanoseconds(static_cast<std::int64_t>(
                                 std::llround(static_cast<double>(paced) * 1e9 / options.rate_hz)));
    clients.service(due);
    if (clients.empty()) continue;
    auto volume = next(sequence);
    if (!volume) break;
    clients.broadcast(encode_igtl_image(*volume, options.device, options.header_version,
                                        static_cast<std::uint32_t>(volume->sequence)));
    sequence = volume->sequence + 1;
    ++paced;
    ++sent;
  }
  log_line("OpenIGTLink server: " + std::to_string(sent) + " volumes sent, stopping");
  // Read what clients still send, so closing does not reset the link before they have it all.
  clients.service(Clock::now() + std::chrono::milliseconds(200));
  ::close(listen_fd);
  return 0;
}

}  // namespace sonomesh::sim::internal
