#include "daemon/internal/igtl_server.h"

#include <netdb.h>
#include <netinet/in.h>
#include <netinet/tcp.h>
#include <poll.h>
#include <spdlog/spdlog.h>
#include <sys/eventfd.h>
#include <sys/socket.h>
#include <unistd.h>

#include <array>
#include <cerrno>
#include <cstring>
#include <stdexcept>

#include "daemon/internal/bounded_queue.h"
#include "daemon/internal/igtl_messages.h"

namespace sonomesh::daemon {

namespace {

constexpr std::size_t kHeaderBytes = 58;  // OpenIGTLink header, versions 1 and 2 alike
constexpr int kPollTimeoutMs = 200;
constexpr int kSendBufferBytes = 1 << 20;  // what a stalled client can hold in the kernel

void set_keepalive(int fd) {
  // A client that vanished without a FIN (cable, crash of its host) is noticed within ~11 s.
  int yes = 1, idle_s = 5, interval_s = 2, count = 3;
  ::setsockopt(fd, SOL_SOCKET, SO_KEEPALIVE, &yes, sizeof yes);
  ::setsockopt(fd, IPPROTO_TCP, TCP_KEEPIDLE, &idle_s, sizeof idle_s);
  ::setsockopt(fd, IPPROTO_TCP, TCP_KEEPINTVL, &interval_s, sizeof interval_s);
  ::setsockopt(fd, IPPROTO_TCP, TCP_KEEPCNT, &count, sizeof count);
  ::setsockopt(fd, IPPROTO_TCP, TCP_NODELAY, &yes, sizeof yes);
  int sndbuf = kSendBufferBytes;
  ::setsockopt(fd, SOL_SOCKET, SO_SNDBUF, &sndbuf, sizeof sndbuf);
}

std::uint64_t big_endian_u64(const unsigned char* p) {
  std::uint64_t v = 0;
  for (int i = 0; i < 8; ++i) v = (v << 8) | p[i];
  return v;
}

int bind_listener(const HttpAddress& address) {
  addrinfo hints{};
  hints.ai_family = AF_UNSPEC;
  hints.ai_socktype = SOCK_STREAM;
  hints.ai_flags = AI_PASSIVE | AI_NUMERICSERV;
  addrinfo* found = nullptr;
  const std::string port = std::to_string(address.port);
  const std::string where = address.host + ":" + port;
  if (::getaddrinfo(address.host.c_str(), port.c_str(), &hints, &found) != 0 || !found) {
    throw std::runtime_error("OpenIGTLink: cannot resolve " + where);
  }
  int fd = -1;
  std::string why = "no address";
  for (addrinfo* a = found; a; a = a->ai_next) {
    fd = ::socket(a->ai_family, a->ai_socktype | SOCK_CLOEXEC | SOCK_NONBLOCK, a->ai_protocol);
    if (fd < 0) continue;
    int yes = 1;
    ::setsockopt(fd, SOL_SOCKET, SO_REUSEADDR, &yes, sizeof yes);
    if (::bind(fd, a->ai_addr, a->ai_addrlen) == 0 && ::listen(fd, 16) == 0) break;
    why = std::strerror(errno);
    ::close(fd);
    fd = -1;
  }
  ::freeaddrinfo(found);
  if (fd < 0) throw std::runtime_error("OpenIGTLink: cannot listen on " + where + ": " + why);
  return fd;
}

int bound_port(int fd) {
  sockaddr_storage addr{};
  socklen_t len = sizeof addr;
  ::getsockname(fd, reinterpret_cast<sockaddr*>(&addr), &len);
  if (addr.ss_family == AF_INET6) return ntohs(reinterpret_cast<sockaddr_in6*>(&addr)->sin6_port);
  return ntohs(reinterpret_cast<sockaddr_in*>(&addr)->sin_port);
}

}  // namespace

struct IgtlServer::Client {
  explicit Client(int f) : fd(f) {}
  ~Client() { ::close(fd); }
  int fd;
  BoundedQueue<std::shared_ptr<const std::string>> queue{kClientQueue, QueueMode::DropOldest};
  std::shared_ptr<const std::string> sending;  // the set being written, and how far
  std::size_t sent_bytes = 0;
  // Reading: the header being collected, then the body being skipped.
  std::array<unsigned char, kHeaderBytes> header{};
  std::size_t header_bytes = 0;
  std::uint64_t body_left = 0;
  bool answer_after_body = false;  // a GET_ query: send the latest set once its body is read
};

IgtlServer::IgtlServer(RunStats& stats) : stats_(stats) {}

IgtlServer::~IgtlServer() { stop(); }

int IgtlServer::start(const HttpAddress& address) {
  listen_fd_ = bind_listener(address);
  wake_fd_ = ::eventfd(0, EFD_CLOEXEC | EFD_NONBLOCK);
  if (wake_fd_ < 0) throw std::runtime_error("OpenIGTLink: eventfd failed");
  const int port = bound_port(listen_fd_);
  update_stats();
  thread_ = std::thread([this] { serve(); });
  packer_ = std::thread([this] { pack_loop(); });
  return port;
}

void IgtlServer::stop() {
  pack_queue_.close();
  if (packer_.joinable()) packer_.join();
  stopping_ = true;
  if (wake_fd_ >= 0) {
    const std::uint64_t one = 1;
    [[maybe_unused]] auto n = ::write(wake_fd_, &one, sizeof one);
  }
  if (thread_.joinable()) thread_.join();
  {
    std::lock_guard lock(mutex_);
    clients_.clear();
  }
  if (listen_fd_ >= 0) ::close(listen_fd_);
  if (wake_fd_ >= 0) ::close(wake_fd_);
  listen_fd_ = wake_fd_ = -1;
}

void IgtlServer::on_line(const nlohmann::json& line, const ProcessedVolume* volume) {
  if (!volume || listen_fd_ < 0) return;
  const std::size_t dropped = pack_queue_.push(PackJob{*volume, line.dump()}).size();
  if (dropped > 0) {
    std::lock_guard lock(mutex_);
    sets_dropped_ += dropped;
  }
}

void IgtlServer::pack_loop() {
  while (auto job = pack_queue_.pop()) {
    try {
      publish(job->volume, job->status_line);
    } catch (const std::exception& e) {
      spdlog::error("OpenIGTLink: {}", e.what());
    }
  }
}

void IgtlServer::publish(const ProcessedVolume& volume, const std::string& status_line) {
  const IgtlTime now = IgtlTime::now();
  // POLYDATA first: it is what Slicer shows, and the end of the measured latency.
  std::string set = pack_igtl_mesh(volume.mesh, now);
  if (volume.labels) set += pack_igtl_labels(*volume.labels, now);
  set += pack_igtl_string(kIgtlStatusDevice, status_line, now);
  auto shared = std::make_shared<const std::string>(std::move(set));
  {
    std::lock_guard lock(mutex_);
    latest_ = shared;
    for (const auto& client : clients_) sets_dropped_ += client->queue.push(shared).size();
  }
  update_stats();
  const std::uint64_t one = 1;
  [[maybe_unused]] auto n = ::write(wake_fd_, &one, sizeof one);
}

void IgtlServer::update_stats() {
  std::lock_guard lock(mutex_);
  stats_.set_igtl(clients_.size(), sets_sent_, sets_dropped_);
}

void IgtlServer::accept_clients() {
  while (true) {
    const int fd = ::accept4(listen_fd_, nullptr, nullptr, SOCK_CLOEXEC | SOCK_NONBLOCK);
    if (fd < 0) return;  // EAGAIN: no more waiting; anything else: try on the next wake-up
    set_keepalive(fd);
    auto client = std::make_shared<Client>(fd);
    std::lock_guard lock(mutex_);
    if (latest_) client->queue.push(latest_);  // a late joiner sees the latest results at once
    clients_.push_back(std::move(client));
    spdlog::info("OpenIGTLink client connected ({} now)", clients_.size());
  }
}

// Reads what the client sent: headers are parsed, bodies skipped unread. False: it is gone.
bool IgtlServer::read_from(Client& c) {
  std::array<unsigned char, 16384> buf;
  while (true) {
    const ssize_t n = ::recv(c.fd, buf.data(), buf.size(), 0);
    if (n == 0) return false;
    if (n < 0) return errno == EAGAIN || errno == EWOULDBLOCK || errno == EINTR;
    for (std::size_t i = 0; i < static_cast<std::size_t>(n);) {
      if (c.body_left > 0) {
        const std::size_t skip = std::min<std::uint64_t>(c.body_left, n - i);
        c.body_left -= skip;
        i += skip;
      } else {
        const std::size_t take = std::min(kHeaderBytes - c.header_bytes, n - i);
        std::memcpy(c.header.data() + c.header_bytes, buf.data() + i, take);
        c.header_bytes += take;
        i += take;
        if (c.header_bytes < kHeaderBytes) continue;
        c.header_bytes = 0;
        c.body_left = big_endian_u64(c.header.data() + 42);
        c.answer_after_body = std::memcmp(c.header.data() + 2, "GET_", 4) == 0;
      }
      if (c.body_left == 0 && c.answer_after_body) {
        c.answer_after_body = false;
        std::lock_guard lock(mutex_);
        if (latest_) sets_dropped_ += c.queue.push(latest_).size();
      }
    }
  }
}

// Writes as much as the socket takes without blocking. False: the client is gone.
bool IgtlServer::write_to(Client& c) {
  while (true) {
    if (!c.sending) {
      auto next = c.queue.pop(std::chrono::milliseconds(0));
      if (!next) return true;
      c.sending = std::move(*next);
      c.sent_bytes = 0;
    }
    const std::string& bytes = *c.sending;
    const ssize_t n =
        ::send(c.fd, bytes.data() + c.sent_bytes, bytes.size() - c.sent_bytes, MSG_NOSIGNAL);
    if (n < 0) return errno == EAGAIN || errno == EWOULDBLOCK || errno == EINTR;
    c.sent_bytes += static_cast<std::size_t>(n);
    if (c.sent_bytes < bytes.size()) continue;
    c.sending.reset();
    std::lock_guard lock(mutex_);
    ++sets_sent_;
  }
}

void IgtlServer::serve() {
  while (!stopping_) {
    std::vector<std::shared_ptr<Client>> clients;
    {
      std::lock_guard lock(mutex_);
      clients = clients_;
    }
    std::vector<pollfd> fds{{wake_fd_, POLLIN, 0}, {listen_fd_, POLLIN, 0}};
    for (const auto& c : clients) {
      const bool pending = c->sending || c->queue.size() > 0;
      fds.push_back({c->fd, static_cast<short>(POLLIN | (pending ? POLLOUT : 0)), 0});
    }
    if (::poll(fds.data(), fds.size(), kPollTimeoutMs) < 0 && errno != EINTR) break;
    if (fds[0].revents & POLLIN) {
      std::uint64_t count;
      [[maybe_unused]] auto n = ::read(wake_fd_, &count, sizeof count);
    }
    if (fds[1].revents & POLLIN) accept_clients();
    std::vector<std::shared_ptr<Client>> gone;
    for (std::size_t i = 0; i < clients.size(); ++i) {
      Client& c = *clients[i];
      const short ev = fds[i + 2].revents;
      bool alive = !(ev & (POLLERR | POLLNVAL));
      if (alive && (ev & (POLLIN | POLLHUP))) alive = read_from(c);
      if (alive) alive = write_to(c);
      if (!alive) gone.push_back(clients[i]);
    }
    if (!gone.empty()) {
      std::lock_guard lock(mutex_);
      for (const auto& g : gone) std::erase(clients_, g);
      spdlog::info("OpenIGTLink client left ({} now)", clients_.size());
    }
    update_stats();
  }
}

}  // namespace sonomesh::daemon
