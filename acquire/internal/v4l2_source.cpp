/// @file
/// @brief v4l2:/dev/videoN - frame-grabber probes: a V4l2Device feeding a SliceAssembler.

#include <linux/videodev2.h>
#include <poll.h>

#include <cerrno>
#include <charconv>
#include <chrono>
#include <cstring>
#include <deque>
#include <optional>
#include <string>
#include <utility>

#include "acquire/internal/backoff.h"
#include "acquire/internal/slice_assembler.h"
#include "acquire/internal/sources.h"
#include "acquire/internal/v4l2_device.h"
#include "acquire/internal/waker.h"

namespace sonomesh::acquire::internal {
namespace {

using Clock = std::chrono::steady_clock;
using Result = tl::expected<RawVolume, AcquireError>;

constexpr int kBufferCount = 4;
// Emulated and some real drivers report the node readable although DQBUF has nothing yet;
// this bounds the retry rate so such a driver cannot make the caller spin.
constexpr std::chrono::milliseconds kEmptyDequeueRetry{2};

AcquireError make_error(AcquireError::Code code, std::string detail) {
  return AcquireError{code, 0, std::move(detail), {}, 0};
}

struct V4l2Spec {
  std::string device;
  int slices = 0;                 // 0 = tagged mode
  std::uint32_t pixelformat = 0;  // 0 = keep GREY/Y16 if current, else GREY
};

tl::expected<V4l2Spec, AcquireError> parse_spec(const SourceUri& uri,
                                                const SourceOptions& options) {
  auto invalid = [&](const std::string& what) {
    return tl::unexpected(make_error(AcquireError::Code::InvalidArgument, uri.text + ": " + what));
  };
  V4l2Spec spec;
  spec.slices = options.v4l2_slices;
  spec.device = uri.body;
  if (spec.device.empty()) {
    return invalid("missing device path (v4l2:/dev/videoN[?slices=N&format=grey|y16])");
  }
  if (auto refused = refuse_unknown_keys(uri, {"slices", "format"})) {
    return tl::unexpected(*refused);
  }
  if (const auto it = uri.query.find("slices"); it != uri.query.end()) {
    const std::string& value = it->second;
    int n = 0;
    const auto [ptr, ec] = std::from_chars(value.data(), value.data() + value.size(), n);
    if (ec != std::errc{} || ptr != value.data() + value.size() || n < 1 || n > 65535) {
      return invalid("slices must be an integer in 1..65535, got '" + value + "'");
    }
    spec.slices = n;
  }
  if (const auto it = uri.query.find("format"); it != uri.query.end()) {
    const std::string& value = it->second;
    if (value == "grey" || value == "GREY") {
      spec.pixelformat = V4L2_PIX_FMT_GREY;
    } else if (value == "y16" || value == "Y16") {
      spec.pixelformat = V4L2_PIX_FMT_Y16;
    } else {
      return invalid("format must be grey or y16, got '" + value + "'");
    }
  }
  return spec;
}

class V4l2Source final : public Source {
 public:
  V4l2Source(V4l2Spec spec, const SourceOptions& options)
      : spec_(std::move(spec)), options_(options) {}

  tl::expected<void, AcquireError> start() { return open_device(); }

  Result next(std::chrono::milliseconds timeout) override {
    const auto deadline = Clock::now() + timeout;
    for (;;) {
      if (auto r = take_ready()) return std::move(*r);
      if (std::exchange(woken_, false) || waker_.drain()) return timeout_error();
      if (!device_.is_open()) {
        // Link is down: reopen with backoff (the device node disappears and returns on replug).
        if (backoff_.due()) {
          if (open_device()) {
            backoff_.succeeded();
            continue;
          }
          backoff_.failed();
        }
        if (Clock::now() >= deadline) return timeout_error();
        woken_ = waker_.sleep_until(std::min(backoff_.next_attempt(), deadline));
        continue;
      }
      if (Clock::now() >= deadline) return timeout_error();
      pollfd fds[2] = {{device_.fd(), POLLIN, 0}, {waker_.fd(), POLLIN, 0}};
      const int pr = ::poll(fds, 2, Waker::poll_ms(deadline));
      if (pr < 0 && errno != EINTR) {
        return tl::unexpected(make_error(AcquireError::Code::IoError,
                                         std::string("v4l2: poll: ") + std::strerror(errno)));
      }
      if (pr <= 0 || (fds[1].revents & POLLIN)) continue;  // the wake is drained at the top
      if (fds[0].revents & (POLLERR | POLLHUP | POLLNVAL)) {
        link_lost("v4l2: " + spec_.device + ": device error/hangup");
        continue;
      }
      dequeue_one(deadline);
    }
  }

  std::string describe() const override {
    std::string d = "v4l2:" + spec_.device;
    if (spec_.slices > 0) d += "?slices=" + std::to_string(spec_.slices);
    return d;
  }
  bool live() const override { return true; }
  void interrupt() override { waker_.wake(); }

 private:
  static Result timeout_error() {
    return tl::unexpected(make_error(AcquireError::Code::Timeout, "no volume within the timeout"));
  }

  // The assembler's results go first: they came from frames before whatever is pushed now.
  void flush_assembler() {
    if (!assembler_) return;
    while (auto r = assembler_->next()) ready_.push_back(std::move(*r));
  }
  void push(Result r) {
    flush_assembler();
    ready_.push_back(std::move(r));
  }
  std::optional<Result> take_ready() {
    flush_assembler();
    if (ready_.empty()) return std::nullopt;
    Result r = std::move(ready_.front());
    ready_.pop_front();
    return r;
  }

  // Opens the device and checks its format against the mode and the limits.
  tl::expected<void, AcquireError> open_device() {
    auto fail = [&](AcquireError e) -> tl::expected<void, AcquireError> {
      device_.close();
      return tl::unexpected(std::move(e));
    };
    const std::string& dev = spec_.device;
    if (auto r = device_.open(dev); !r) return r;
    auto fmt = device_.set_format(spec_.pixelformat);
    if (!fmt) return fail(fmt.error());
    SliceFormat f{
        fmt->width, fmt->height, fmt->stride,
        fmt->pixelformat == V4L2_PIX_FMT_Y16 ? ProbeVoxelType::UInt16 : ProbeVoxelType::UInt8,
        spec_.slices};
    const bool tagged = spec_.slices == 0;
    const auto row_bytes =
        static_cast<std::size_t>(f.width) * static_cast<std::size_t>(bytes_per_voxel(f.type));
    if (f.width < 1 || f.height < 1 || (tagged && (f.height < 2 || row_bytes < kSliceTagBytes))) {
      return fail(make_error(AcquireError::Code::InvalidArgument,
                             "v4l2: " + dev + ": frame " + std::to_string(f.width) + "x" +
                                 std::to_string(f.height) + " too small for " +
                                 (tagged ? "a slice tag" : "slices")));
    }
    if (f.width > options_.max_dims[0] ||
        (tagged ? f.height - 1 : f.height) > options_.max_dims[1]) {
      return fail(make_error(AcquireError::Code::InvalidArgument,
                             "v4l2: " + dev + ": frame size exceeds the configured maximum dims"));
    }
    if (!tagged && spec_.slices > options_.max_dims[2]) {
      return fail(make_error(AcquireError::Code::InvalidArgument,
                             "v4l2: slices exceeds the configured maximum nz"));
    }
    if (auto r = device_.allocate_buffers(kBufferCount); !r) return fail(r.error());
    if (auto r = device_.stream_on(); !r) return fail(r.error());
    // A fresh stream starts with a fresh frame counter: partial state from before is dropped.
    if (!assembler_) {
      assembler_.emplace(f, options_);
    } else {
      assembler_->restart("stream restarted", f);
    }
    return {};
  }

  void link_lost(const std::string& detail) {
    device_.close();
    // The volume in progress cannot complete any more.
    if (assembler_) assembler_->restart("link lost mid-volume", assembler_->format());
    AcquireError e = make_error(AcquireError::Code::Disconnected, detail);
    e.os_errno = ENODEV;
    push(tl::unexpected(std::move(e)));
    backoff_.dropped();
  }

  /// DQBUF is the real blocking point: poll() may report ready without a frame.
  void dequeue_one(Clock::time_point deadline) {
    auto got = device_.dequeue();
    if (!got) {
      if (got.error().code == AcquireError::Code::Disconnected)
        return link_lost(got.error().detail);
      push(tl::unexpected(got.error()));
      return;
    }
    if (!*got) {
      woken_ = waker_.sleep_until(std::min(deadline, Clock::now() + kEmptyDequeueRetry));
      return;
    }
    assembler_->take((*got)->frame);
    if (auto r = device_.requeue((*got)->index); !r) {
      if (r.error().code == AcquireError::Code::Disconnected) return link_lost(r.error().detail);
      push(tl::unexpected(r.error()));
    }
  }

  V4l2Spec spec_;
  SourceOptions options_;
  V4l2Device device_;
  std::optional<SliceAssembler> assembler_;
  std::deque<Result> ready_;
  Waker waker_;
  bool woken_ = false;  // a sleep consumed an interrupt(): next() returns Timeout
  Backoff backoff_;
};

}  // namespace

OpenResult open_v4l2_source(const SourceUri& uri, const SourceOptions& options) {
  auto spec = parse_spec(uri, options);
  if (!spec) return tl::unexpected(spec.error());
  auto source = std::make_unique<V4l2Source>(std::move(*spec), options);
  if (auto started = source->start(); !started) return tl::unexpected(started.error());
  return source;
}

}  // namespace sonomesh::acquire::internal
