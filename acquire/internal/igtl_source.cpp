// igtl:HOST:PORT[?device=NAME] - IMAGE messages from an OpenIGTLink server as volumes.
#include <poll.h>
#include <sys/socket.h>
#include <unistd.h>

#include <cerrno>
#include <cstring>
#include <deque>

#include "acquire/igtl.h"
#include "acquire/internal/socket_connect.h"
#include "acquire/internal/sources.h"

namespace sonomesh::acquire::internal {
namespace {

using Clock = std::chrono::steady_clock;
using Result = tl::expected<RawVolume, AcquireError>;
using Reader = igtl::MessageReader;

constexpr std::size_t kReadChunk = 1 << 20;
// Room for a version-2 extended header and metadata next to the image (PLUS sends a few keys).
constexpr std::uint64_t kBodyOverheadBytes = 1 << 20;

AcquireError error(AcquireError::Code code, std::string detail,
                   std::optional<std::uint64_t> sequence = std::nullopt, int err = 0) {
  return AcquireError{code, err, std::move(detail), sequence, 0};
}

class IgtlSource final : public Source {
 public:
  IgtlSource(Endpoint endpoint, std::string device, const SourceOptions& options)
      : endpoint_(std::move(endpoint)),
        device_(std::move(device)),
        options_(options),
        limits_{options.max_dims, options.max_payload_bytes},
        reader_(options.max_payload_bytes + igtl::kImageHeaderBytes + kBodyOverheadBytes),
        buffer_(kReadChunk) {}
  ~IgtlSource() override { close_fd(); }
  IgtlSource(const IgtlSource&) = delete;
  IgtlSource& operator=(const IgtlSource&) = delete;

  tl::expected<void, AcquireError> connect_now() {
    auto fd = connect_stream(endpoint_, Clock::now() + options_.connect_timeout, waker_);
    if (!fd) return tl::make_unexpected(fd.error());
    adopt(*fd);
    return {};
  }

  Result next(std::chrono::milliseconds timeout) override {
    const auto deadline = Clock::now() + timeout;
    for (;;) {
      if (!ready_.empty()) {
        Result r = std::move(ready_.front());
        ready_.pop_front();
        return r;
      }
      if (fd_ < 0) {
        if (!reconnect(deadline)) return timeout_error();
        continue;
      }
      const SocketWait wait = wait_readable(fd_, waker_, deadline);
      if (wait == SocketWait::Failed) {
        return tl::make_unexpected(error(AcquireError::Code::IoError,
                                         std::string("poll: ") + std::strerror(errno), {}, errno));
      }
      if (wait == SocketWait::Timeout) return timeout_error();
      receive();
    }
  }

  std::string describe() const override { return endpoint_.uri; }
  bool live() const override { return true; }
  void interrupt() override { waker_.wake(); }

 private:
  static Result timeout_error() {
    return tl::make_unexpected(error(AcquireError::Code::Timeout, "no volume"));
  }

  void adopt(int fd) {
    fd_ = fd;
    const int on = 1;  // a server that vanishes without a FIN is noticed eventually
    ::setsockopt(fd_, SOL_SOCKET, SO_KEEPALIVE, &on, sizeof on);
  }

  void close_fd() {
    if (fd_ >= 0) ::close(fd_);
    fd_ = -1;
  }

  // One reconnect step; false if the caller should return Timeout.
  bool reconnect(Clock::time_point deadline) {
    const std::optional<int> fd =
        reconnect_step(endpoint_, backoff_, waker_, deadline, options_.connect_timeout);
    if (!fd) return false;
    if (*fd >= 0) adopt(*fd);
    return true;
  }

  void receive() {
    const auto down = receive_available(fd_, buffer_, "server", [this](const auto* data, auto n) {
      reader_.feed(data, n);
      while (auto event = reader_.next()) take(std::move(*event));
      return fd_ >= 0;  // a message may have ended the link
    });
    if (down) link_down(down->why, down->err);
  }

  void link_down(const std::string& why, int err) {
    close_fd();
    if (auto event = reader_.end_of_input()) take(std::move(*event));
    ready_.push_back(tl::make_unexpected(
        error(AcquireError::Code::Disconnected, endpoint_.uri + ": " + why, {}, err)));
    backoff_.dropped();
  }

  bool wanted(const igtl::Header& h) const {
    return h.type == "IMAGE" && (device_.empty() || h.device == device_);
  }
  std::string name(const igtl::Header& h) const {
    return endpoint_.uri + ": IMAGE '" + h.device + "'";
  }
  void reject(const igtl::Header& h, const std::string& why,
              AcquireError::Code code = AcquireError::Code::BadRecord) {
    ready_.push_back(tl::make_unexpected(error(code, name(h) + ": " + why, next_sequence_++)));
  }

  void take(Reader::Event event) {
    if (auto* m = std::get_if<Reader::Message>(&event)) return take_message(*m);
    if (auto* big = std::get_if<Reader::Oversize>(&event)) {
      if (wanted(big->header)) {
        reject(big->header, "body of " + std::to_string(big->header.body_bytes) +
                                " bytes exceeds the limit (skipped unread)");
      }
      return;
    }
    if (auto* cut = std::get_if<Reader::Truncated>(&event)) {
      if (wanted(cut->header) && !cut->oversize) {
        reject(cut->header,
               "connection closed after " + std::to_string(cut->got_bytes) + " of " +
                   std::to_string(cut->header.body_bytes) + " body bytes",
               AcquireError::Code::Incomplete);
      }
      return;
    }
    // The stream cannot be framed any more: report it and start over on a new connection.
    const auto& lost = std::get<Reader::FramingLost>(event);
    ready_.push_back(tl::make_unexpected(
        error(AcquireError::Code::BadRecord, endpoint_.uri + ": framing lost: " + lost.why)));
    reader_.reset();
    link_down("reconnecting after the framing was lost", 0);
  }

  void take_message(const Reader::Message& m) {
    const bool want = wanted(m.header);
    if (!m.crc_ok) {
      if (want) reject(m.header, "CRC-64 mismatch");
      return;
    }
    auto content = igtl::message_content(m.header, m.body);
    if (!content) {
      if (want) reject(m.header, content.error());
      return;
    }
    if (content->message_id) note_message_id(*content->message_id);
    if (!want) return;  // other types and devices are read and skipped
    auto volume = igtl::decode_image(content->data, content->size, limits_);
    if (!volume) return reject(m.header, volume.error());
    volume->sequence = next_sequence_++;
    volume->timestamp_ns = igtl::timestamp_ns(m.header.timestamp);
    volume->received = Clock::now();
    ready_.push_back(std::move(*volume));
  }

  // MESSAGE_IDs number the server's messages: ids skipped since the last one were lost (each
  // counted as a volume: its type is unknown). A lower id means the server started numbering anew.
  void note_message_id(std::uint32_t id) {
    if (last_message_id_ && id > *last_message_id_ + 1) {
      const std::uint64_t missing = id - *last_message_id_ - 1;
      AcquireError lost = error(AcquireError::Code::Lost,
                                endpoint_.uri + ": " + std::to_string(missing) +
                                    " message(s) missing before MESSAGE_ID " + std::to_string(id),
                                next_sequence_);
      lost.count = missing;
      ready_.push_back(tl::make_unexpected(std::move(lost)));
      next_sequence_ += missing;
    }
    last_message_id_ = id;
  }

  Endpoint endpoint_;
  std::string device_;  // empty: every device
  SourceOptions options_;
  igtl::ImageLimits limits_;
  Reader reader_;
  std::vector<std::uint8_t> buffer_;
  std::deque<Result> ready_;
  Waker waker_;
  int fd_ = -1;
  Backoff backoff_;
  std::uint64_t next_sequence_ = 0;  // arrival order of the wanted IMAGEs (and of lost messages)
  std::optional<std::uint32_t> last_message_id_;
};

}  // namespace

OpenResult open_igtl_source(const SourceUri& uri, const SourceOptions& options) {
  if (auto refused = refuse_unknown_keys(uri, {"device"})) return tl::make_unexpected(*refused);
  auto endpoint = tcp_endpoint(uri.body, uri.text);
  if (!endpoint) {
    return tl::make_unexpected(error(AcquireError::Code::InvalidArgument,
                                     uri.text + ": expected igtl:HOST:PORT[?device=NAME]"));
  }
  std::string device;
  if (const auto it = uri.query.find("device"); it != uri.query.end()) {
    device = it->second;
    if (device.empty() || device.size() > 20) {
      return tl::make_unexpected(error(AcquireError::Code::InvalidArgument,
                                       uri.text + ": device name must be 1..20 characters"));
    }
  }
  auto source = std::make_unique<IgtlSource>(std::move(*endpoint), std::move(device), options);
  if (auto r = source->connect_now(); !r) return tl::make_unexpected(r.error());
  return source;
}

}  // namespace sonomesh::acquire::internal
