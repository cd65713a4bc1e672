// unix:PATH and tcp:HOST:PORT: probe stream client with reconnect and interrupt.
#include <poll.h>
#include <sys/socket.h>
#include <sys/un.h>
#include <unistd.h>

#include <cerrno>
#include <cstring>
#include <deque>
#include <vector>

#include "acquire/internal/socket_connect.h"
#include "acquire/internal/sources.h"
#include "acquire/internal/stream_decoder.h"
#include "acquire/internal/waker.h"

namespace sonomesh::acquire::internal {
namespace {

using Clock = std::chrono::steady_clock;
using std::chrono::milliseconds;

constexpr std::size_t kReadChunk = 1 << 20;

AcquireError os_error(AcquireError::Code code, int err, std::string what) {
  return AcquireError{code, err, what + ": " + std::strerror(err), {}, 0};
}

class SocketSource final : public Source {
 public:
  SocketSource(Endpoint endpoint, const SourceOptions& options)
      : endpoint_(std::move(endpoint)), options_(options), decoder_(options), buffer_(kReadChunk) {}
  ~SocketSource() override { close_fd(); }

  tl::expected<void, AcquireError> connect_now(milliseconds timeout) {
    auto fd = connect_stream(endpoint_, Clock::now() + timeout, waker_);
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
        const std::optional<int> fd =
            reconnect_step(endpoint_, backoff_, waker_, deadline, options_.connect_timeout);
        if (!fd) return timeout_error();
        fd_ = *fd;
        continue;
      }
      const SocketWait wait = wait_readable(fd_, waker_, deadline);
      if (wait == SocketWait::Failed) {
        return tl::make_unexpected(os_error(AcquireError::Code::IoError, errno, "poll"));
      }
      if (wait == SocketWait::Timeout) return timeout_error();
      receive();
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

  void receive() {
    const auto down = receive_available(fd_, buffer_, "probe", [this](const auto* data, auto n) {
      decoder_.feed(data, n);
      return true;
    });
    if (down) link_down(down->why, down->err);
  }

  void link_down(const std::string& why, int err) {
    close_fd();
    decoder_.end_of_input();
    while (auto r = decoder_.next()) ready_.push_back(std::move(*r));
    if (!decoder_.end_of_stream_seen()) {
      ready_.push_back(tl::make_unexpected(
          AcquireError{AcquireError::Code::Disconnected, err, endpoint_.uri + ": " + why, {}, 0}));
    }
    backoff_.dropped();
  }

  Endpoint endpoint_;
  SourceOptions options_;
  StreamDecoder decoder_;
  std::vector<std::uint8_t> buffer_;
  std::deque<NextResult> ready_;
  Waker waker_;
  int fd_ = -1;
  bool finished_ = false;
  Backoff backoff_;
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

OpenResult open_unix_source(const SourceUri& uri, const SourceOptions& options) {
  if (auto refused = refuse_unknown_keys(uri, {})) return tl::make_unexpected(*refused);
  const std::string& path = uri.body;
  if (path.empty() || path.size() >= sizeof(sockaddr_un{}.sun_path)) {
    return tl::make_unexpected(AcquireError{AcquireError::Code::InvalidArgument,
                                            0,
                                            uri.text + ": socket path must be 1.." +
                                                std::to_string(sizeof(sockaddr_un{}.sun_path) - 1) +
                                                " characters",
                                            {},
                                            0});
  }
  return open_socket(Endpoint{true, path, "", "", uri.text}, options);
}

OpenResult open_tcp_source(const SourceUri& uri, const SourceOptions& options) {
  if (auto refused = refuse_unknown_keys(uri, {})) return tl::make_unexpected(*refused);
  auto endpoint = tcp_endpoint(uri.body, uri.text);
  if (!endpoint) {
    return tl::make_unexpected(AcquireError{
        AcquireError::Code::InvalidArgument, 0, uri.text + ": expected tcp:HOST:PORT", {}, 0});
  }
  return open_socket(std::move(*endpoint), options);
}

}  // namespace sonomesh::acquire::internal
