/// @file
/// @brief V4L2 frame-grabber probes: one slice per frame, assembled into volumes.
///
/// Plain libc open/ioctl/mmap streaming (no libv4l2: it issues raw syscalls that neither
/// LD_PRELOAD-based emulation nor some sandboxes see, and GREY/Y16 need no conversion).
/// Tagged mode: row 0 of every frame starts with a 32-byte slice tag (magic "USS1", u64 volume
/// sequence, u16 slice index, u16 slice count, 3 x f32 spacing_mm, u32 crc32 of bytes 0..27);
/// the slice image is rows 1..H-1. Untagged mode: N consecutive frames are one volume, aligned on
/// the driver's frame counter so that a dropped frame spoils only the volume it belonged to.

#include <fcntl.h>
#include <linux/videodev2.h>
#include <poll.h>
#include <sys/eventfd.h>
#include <sys/ioctl.h>
#include <sys/mman.h>
#include <unistd.h>
#include <zlib.h>

#include <algorithm>
#include <atomic>
#include <cerrno>
#include <charconv>
#include <chrono>
#include <cstring>
#include <deque>
#include <optional>
#include <string>
#include <string_view>
#include <vector>

#include "acquire/acquire.h"
#include "acquire/internal/sources.h"
#include "acquire/protocol.h"

namespace sonomesh::acquire::internal {
namespace {

using Clock = std::chrono::steady_clock;
using Result = tl::expected<RawVolume, AcquireError>;

constexpr std::size_t kSliceTagBytes = 32;
constexpr int kBufferCount = 4;
// Emulated and some real drivers report the node readable although DQBUF has nothing yet;
// this bounds the retry rate so such a driver cannot make the caller spin.
constexpr std::chrono::milliseconds kEmptyDequeueRetry{2};

AcquireError make_error(AcquireError::Code code, std::string detail, int os_errno = 0) {
  AcquireError e;
  e.code = code;
  e.detail = std::move(detail);
  e.os_errno = os_errno;
  return e;
}

AcquireError errno_error(const std::string& what, int err) {
  const auto code = (err == ENODEV || err == ENXIO) ? AcquireError::Code::Disconnected
                                                    : AcquireError::Code::IoError;
  return make_error(code, what + ": " + std::strerror(err), err);
}

int xioctl(int fd, unsigned long request, void* arg) {
  int r;
  do {
    r = ::ioctl(fd, request, arg);
  } while (r == -1 && errno == EINTR);
  return r;
}

template <typename T>
T load_le(const std::uint8_t* p) {
  T v;
  std::memcpy(&v, p, sizeof v);  // host is little endian (x86-64/aarch64), as is the tag
  return v;
}

struct V4l2Spec {
  std::string device;
  int slices = 0;            // 0 = tagged mode
  std::uint32_t pixelformat = 0;  // 0 = keep GREY/Y16 if current, else GREY
};

tl::expected<V4l2Spec, AcquireError> parse_spec(std::string_view target, const SourceOptions& options) {
  V4l2Spec spec;
  spec.slices = options.v4l2_slices;
  const auto q = target.find('?');
  spec.device = std::string(target.substr(0, q));
  if (spec.device.empty())
    return tl::unexpected(make_error(AcquireError::Code::InvalidArgument,
                                     "v4l2: missing device path (v4l2:/dev/videoN[?slices=N&format=grey|y16])"));
  if (q == std::string_view::npos) return spec;
  std::string_view query = target.substr(q + 1);
  while (!query.empty()) {
    const auto amp = query.find('&');
    const std::string_view item = query.substr(0, amp);
    query = amp == std::string_view::npos ? std::string_view{} : query.substr(amp + 1);
    const auto eq = item.find('=');
    const std::string_view key = item.substr(0, eq);
    const std::string_view value = eq == std::string_view::npos ? std::string_view{} : item.substr(eq + 1);
    if (key == "slices") {
      int n = 0;
      const auto [ptr, ec] = std::from_chars(value.data(), value.data() + value.size(), n);
      if (ec != std::errc{} || ptr != value.data() + value.size() || n < 1 || n > 65535)
        return tl::unexpected(make_error(AcquireError::Code::InvalidArgument,
                                         "v4l2: slices must be an integer in 1..65535, got '" +
                                             std::string(value) + "'"));
      spec.slices = n;
    } else if (key == "format") {
      if (value == "grey" || value == "GREY")
        spec.pixelformat = V4L2_PIX_FMT_GREY;
      else if (value == "y16" || value == "Y16")
        spec.pixelformat = V4L2_PIX_FMT_Y16;
      else
        return tl::unexpected(make_error(AcquireError::Code::InvalidArgument,
                                         "v4l2: format must be grey or y16, got '" + std::string(value) + "'"));
    } else {
      return tl::unexpected(make_error(AcquireError::Code::InvalidArgument,
                                       "v4l2: unknown option '" + std::string(key) + "' (slices, format)"));
    }
  }
  return spec;
}

/// One dequeued frame, copied out of the driver buffer so the buffer can go straight back.
struct Frame {
  const std::uint8_t* data = nullptr;  // valid until the buffer is re-queued
  std::size_t bytes = 0;
  std::uint32_t driver_sequence = 0;
  std::uint64_t timestamp_ns = 0;
  bool error = false;
};

class V4l2Source final : public Source {
 public:
  V4l2Source(V4l2Spec spec, SourceOptions options) : spec_(std::move(spec)), options_(std::move(options)) {}

  ~V4l2Source() override {
    close_device();
    if (wake_fd_ >= 0) ::close(wake_fd_);
  }

  V4l2Source(const V4l2Source&) = delete;
  V4l2Source& operator=(const V4l2Source&) = delete;

  tl::expected<void, AcquireError> start() {
    wake_fd_ = ::eventfd(0, EFD_NONBLOCK | EFD_CLOEXEC);
    if (wake_fd_ < 0) return tl::unexpected(errno_error("v4l2: eventfd", errno));
    return open_device();
  }

  Result next(std::chrono::milliseconds timeout) override {
    const auto deadline = Clock::now() + timeout;
    for (;;) {
      if (!ready_.empty()) {
        Result r = std::move(ready_.front());
        ready_.pop_front();
        return r;
      }
      if (interrupted_.exchange(false)) return timeout_error();
      if (fd_ < 0) {
        // Link is down: reopen with backoff (the device node disappears and returns on replug).
        if (Clock::now() >= next_attempt_) {
          if (auto opened = open_device(); !opened) {
            backoff_ = std::min(backoff_ * 2, std::chrono::milliseconds(500));
            next_attempt_ = Clock::now() + backoff_;
          } else {
            backoff_ = std::chrono::milliseconds(50);
            continue;
          }
        }
        const auto wake_at = std::min(next_attempt_, deadline);
        if (Clock::now() >= deadline) return timeout_error();
        wait_wake(wake_at);
        continue;
      }
      const auto now = Clock::now();
      if (now >= deadline) return timeout_error();
      const int wait_ms = static_cast<int>(
          std::chrono::ceil<std::chrono::milliseconds>(deadline - now).count());
      pollfd fds[2] = {{fd_, POLLIN, 0}, {wake_fd_, POLLIN, 0}};
      const int pr = ::poll(fds, 2, wait_ms);
      if (pr < 0 && errno != EINTR) return tl::unexpected(errno_error("v4l2: poll", errno));
      if (pr <= 0) continue;
      if (fds[1].revents & POLLIN) {
        drain_wake();
        continue;
      }
      if (fds[0].revents & (POLLERR | POLLHUP | POLLNVAL)) {
        link_lost("v4l2: " + spec_.device + ": device error/hangup", ENODEV);
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
  void interrupt() override {
    interrupted_.store(true);
    const std::uint64_t one = 1;
    [[maybe_unused]] const auto n = ::write(wake_fd_, &one, sizeof one);
  }

 private:
  static Result timeout_error() { return tl::unexpected(make_error(AcquireError::Code::Timeout, "no volume within the timeout")); }

  void wait_wake(Clock::time_point until) {
    const auto now = Clock::now();
    if (until <= now) return;
    const int ms = static_cast<int>(std::chrono::ceil<std::chrono::milliseconds>(until - now).count());
    pollfd p{wake_fd_, POLLIN, 0};
    if (::poll(&p, 1, ms) > 0) drain_wake();
  }
  void drain_wake() {
    std::uint64_t v;
    while (::read(wake_fd_, &v, sizeof v) > 0) {
    }
  }

  tl::expected<void, AcquireError> open_device() {
    const std::string& dev = spec_.device;
    fd_ = ::open(dev.c_str(), O_RDWR | O_NONBLOCK | O_CLOEXEC);
    if (fd_ < 0) {
      const int err = errno;
      return tl::unexpected(make_error(err == ENOENT ? AcquireError::Code::NotFound : AcquireError::Code::IoError,
                                       "v4l2: cannot open " + dev + ": " + std::strerror(err), err));
    }
    auto fail = [&](AcquireError e) -> tl::expected<void, AcquireError> {
      close_device();
      return tl::unexpected(std::move(e));
    };

    v4l2_capability cap{};
    if (xioctl(fd_, VIDIOC_QUERYCAP, &cap) < 0) return fail(errno_error("v4l2: " + dev + ": VIDIOC_QUERYCAP", errno));
    const std::uint32_t caps = (cap.capabilities & V4L2_CAP_DEVICE_CAPS) ? cap.device_caps : cap.capabilities;
    if (!(caps & V4L2_CAP_VIDEO_CAPTURE) || !(caps & V4L2_CAP_STREAMING))
      return fail(make_error(AcquireError::Code::InvalidArgument,
                             "v4l2: " + dev + " is not a streaming video capture device"));

    v4l2_format fmt{};
    fmt.type = V4L2_BUF_TYPE_VIDEO_CAPTURE;
    if (xioctl(fd_, VIDIOC_G_FMT, &fmt) < 0) return fail(errno_error("v4l2: " + dev + ": VIDIOC_G_FMT", errno));
    std::uint32_t want = spec_.pixelformat;
    if (want == 0)
      want = (fmt.fmt.pix.pixelformat == V4L2_PIX_FMT_Y16) ? V4L2_PIX_FMT_Y16 : V4L2_PIX_FMT_GREY;
    fmt.fmt.pix.pixelformat = want;
    fmt.fmt.pix.field = V4L2_FIELD_NONE;
    fmt.fmt.pix.bytesperline = 0;  // let the driver choose its stride
    if (xioctl(fd_, VIDIOC_S_FMT, &fmt) < 0) return fail(errno_error("v4l2: " + dev + ": VIDIOC_S_FMT", errno));
    if (fmt.fmt.pix.pixelformat != want)
      return fail(make_error(AcquireError::Code::InvalidArgument,
                             "v4l2: " + dev + " does not support the requested GREY/Y16 format"));
    width_ = static_cast<int>(fmt.fmt.pix.width);
    height_ = static_cast<int>(fmt.fmt.pix.height);
    type_ = want == V4L2_PIX_FMT_Y16 ? ProbeVoxelType::UInt16 : ProbeVoxelType::UInt8;
    const std::size_t bpp = static_cast<std::size_t>(bytes_per_voxel(type_));
    stride_ = std::max<std::size_t>(fmt.fmt.pix.bytesperline, static_cast<std::size_t>(width_) * bpp);
    if (width_ < 1 || height_ < 1 || (tagged() && (height_ < 2 || width_ * bpp < kSliceTagBytes)))
      return fail(make_error(AcquireError::Code::InvalidArgument,
                             "v4l2: " + dev + ": frame " + std::to_string(width_) + "x" + std::to_string(height_) +
                                 " too small for " + (tagged() ? "a slice tag" : "slices")));
    if (width_ > options_.max_dims[0] || slice_rows() > options_.max_dims[1])
      return fail(make_error(AcquireError::Code::InvalidArgument,
                             "v4l2: " + dev + ": frame size exceeds the configured maximum dims"));
    if (!tagged() && spec_.slices > options_.max_dims[2])
      return fail(make_error(AcquireError::Code::InvalidArgument, "v4l2: slices exceeds the configured maximum nz"));

    v4l2_requestbuffers req{};
    req.count = kBufferCount;
    req.type = V4L2_BUF_TYPE_VIDEO_CAPTURE;
    req.memory = V4L2_MEMORY_MMAP;
    if (xioctl(fd_, VIDIOC_REQBUFS, &req) < 0) return fail(errno_error("v4l2: " + dev + ": VIDIOC_REQBUFS", errno));
    if (req.count < 2) return fail(make_error(AcquireError::Code::IoError, "v4l2: " + dev + ": too few buffers"));
    for (std::uint32_t i = 0; i < req.count; ++i) {
      v4l2_buffer buf{};
      buf.type = V4L2_BUF_TYPE_VIDEO_CAPTURE;
      buf.memory = V4L2_MEMORY_MMAP;
      buf.index = i;
      if (xioctl(fd_, VIDIOC_QUERYBUF, &buf) < 0) return fail(errno_error("v4l2: " + dev + ": VIDIOC_QUERYBUF", errno));
      void* p = ::mmap(nullptr, buf.length, PROT_READ | PROT_WRITE, MAP_SHARED, fd_, buf.m.offset);
      if (p == MAP_FAILED) return fail(errno_error("v4l2: " + dev + ": mmap", errno));
      buffers_.push_back({static_cast<std::uint8_t*>(p), buf.length});
    }
    for (std::uint32_t i = 0; i < buffers_.size(); ++i)
      if (!queue_buffer(i)) return fail(errno_error("v4l2: " + dev + ": VIDIOC_QBUF", errno));
    int type = V4L2_BUF_TYPE_VIDEO_CAPTURE;
    if (xioctl(fd_, VIDIOC_STREAMON, &type) < 0) return fail(errno_error("v4l2: " + dev + ": VIDIOC_STREAMON", errno));
    streaming_ = true;
    // A fresh stream starts with a fresh frame counter: drop partial state from before.
    reset_assembly();
    return {};
  }

  void close_device() {
    if (fd_ < 0) return;
    if (streaming_) {
      int type = V4L2_BUF_TYPE_VIDEO_CAPTURE;
      xioctl(fd_, VIDIOC_STREAMOFF, &type);
      streaming_ = false;
    }
    for (auto& b : buffers_) ::munmap(b.data, b.length);
    buffers_.clear();
    if (fd_ >= 0) {
      // Release the buffers (count 0) so a later open can reallocate them.
      v4l2_requestbuffers req{};
      req.type = V4L2_BUF_TYPE_VIDEO_CAPTURE;
      req.memory = V4L2_MEMORY_MMAP;
      xioctl(fd_, VIDIOC_REQBUFS, &req);
      ::close(fd_);
    }
    fd_ = -1;
  }

  bool queue_buffer(std::uint32_t index) {
    v4l2_buffer buf{};
    buf.type = V4L2_BUF_TYPE_VIDEO_CAPTURE;
    buf.memory = V4L2_MEMORY_MMAP;
    buf.index = index;
    return xioctl(fd_, VIDIOC_QBUF, &buf) == 0;
  }

  void link_lost(const std::string& detail, int err) {
    close_device();
    // The volume in progress cannot complete any more.
    if (assembling_) push_incomplete(cur_seq_, "link lost mid-volume");
    reset_assembly();
    ready_.push_back(tl::unexpected(make_error(AcquireError::Code::Disconnected, detail, err)));
    backoff_ = std::chrono::milliseconds(50);
    next_attempt_ = Clock::now() + backoff_;
  }

  /// DQBUF is the real blocking point: poll() may report ready without a frame.
  void dequeue_one(Clock::time_point deadline) {
    v4l2_buffer buf{};
    buf.type = V4L2_BUF_TYPE_VIDEO_CAPTURE;
    buf.memory = V4L2_MEMORY_MMAP;
    if (xioctl(fd_, VIDIOC_DQBUF, &buf) < 0) {
      const int err = errno;
      if (err == EAGAIN) {
        wait_wake(std::min(deadline, Clock::now() + kEmptyDequeueRetry));
        return;
      }
      if (err == ENODEV || err == ENXIO || err == EIO || err == EPIPE) {
        link_lost("v4l2: " + spec_.device + ": VIDIOC_DQBUF: " + std::strerror(err), err);
        return;
      }
      ready_.push_back(tl::unexpected(errno_error("v4l2: " + spec_.device + ": VIDIOC_DQBUF", err)));
      return;
    }
    if (buf.index >= buffers_.size()) {
      ready_.push_back(tl::unexpected(make_error(AcquireError::Code::IoError, "v4l2: driver returned a bad buffer index")));
      return;
    }
    Frame f;
    f.data = buffers_[buf.index].data;
    f.bytes = std::min<std::size_t>(buf.bytesused ? buf.bytesused : buffers_[buf.index].length,
                                    buffers_[buf.index].length);
    f.driver_sequence = buf.sequence;
    f.timestamp_ns = static_cast<std::uint64_t>(buf.timestamp.tv_sec) * 1000000000ull +
                     static_cast<std::uint64_t>(buf.timestamp.tv_usec) * 1000ull;
    f.error = (buf.flags & V4L2_BUF_FLAG_ERROR) != 0;
    if (tagged())
      take_tagged(f);
    else
      take_untagged(f);
    if (!queue_buffer(buf.index)) {
      const int err = errno;
      if (err == ENODEV || err == ENXIO)
        link_lost("v4l2: " + spec_.device + ": VIDIOC_QBUF: " + std::strerror(err), err);
      else
        ready_.push_back(tl::unexpected(errno_error("v4l2: " + spec_.device + ": VIDIOC_QBUF", err)));
    }
  }

  bool tagged() const { return spec_.slices == 0; }
  int slice_rows() const { return tagged() ? height_ - 1 : height_; }
  std::size_t slice_bytes() const {
    return static_cast<std::size_t>(width_) * static_cast<std::size_t>(slice_rows()) *
           static_cast<std::size_t>(bytes_per_voxel(type_));
  }

  void reset_assembly() {
    assembling_ = false;
    discarding_ = false;
    have_untagged_base_ = false;
    expected_index_ = 0;
  }

  /// Copies rows [first_row, height) of the frame into slice slot `index` of the volume.
  bool copy_slice(const Frame& f, int first_row, int index) {
    const std::size_t row_bytes = static_cast<std::size_t>(width_) * static_cast<std::size_t>(bytes_per_voxel(type_));
    const std::size_t needed = stride_ * static_cast<std::size_t>(height_ - 1) + row_bytes;
    if (f.bytes < needed) return false;
    std::uint8_t* dst = volume_.voxels.data() + static_cast<std::size_t>(index) * slice_bytes();
    for (int r = first_row; r < height_; ++r, dst += row_bytes)
      std::memcpy(dst, f.data + static_cast<std::size_t>(r) * stride_, row_bytes);
    return true;
  }

  void push_incomplete(std::uint64_t seq, const std::string& why) {
    AcquireError e = make_error(AcquireError::Code::Incomplete,
                                "v4l2: volume " + std::to_string(seq) + " incomplete: " + why);
    e.sequence = seq;
    // The volume was seen (just not whole): it must not later count as lost.
    note_sequence(seq);
    ready_.push_back(tl::unexpected(std::move(e)));
  }

  void push_bad_record(std::string detail) {
    ready_.push_back(tl::unexpected(make_error(AcquireError::Code::BadRecord, std::move(detail))));
  }

  /// Sequence bookkeeping: a gap before `seq` is reported as Lost before the volume.
  void note_sequence(std::uint64_t seq) {
    if (auto gap = tracker_.observe_volume(seq)) {
      AcquireError e = make_error(AcquireError::Code::Lost,
                                  "v4l2: " + std::to_string(gap->count) + " volume(s) missing before " +
                                      std::to_string(seq));
      e.sequence = gap->first_missing;
      e.count = gap->count;
      ready_.push_back(tl::unexpected(std::move(e)));
    }
  }

  void finish_volume() {
    volume_.received = Clock::now();
    note_sequence(volume_.sequence);
    ready_.push_back(std::move(volume_));
    volume_ = RawVolume{};
    assembling_ = false;
  }

  bool start_volume(std::uint64_t seq, int count, const std::array<float, 3>& spacing, std::uint64_t ts) {
    const std::uint64_t bytes = static_cast<std::uint64_t>(slice_bytes()) * static_cast<std::uint64_t>(count);
    if (count > options_.max_dims[2] || bytes > options_.max_payload_bytes) {
      AcquireError e = make_error(AcquireError::Code::BadRecord,
                                  "v4l2: volume " + std::to_string(seq) + " with " + std::to_string(count) +
                                      " slices exceeds the configured limits");
      e.sequence = seq;
      ready_.push_back(tl::unexpected(std::move(e)));
      return false;
    }
    volume_ = RawVolume{};
    volume_.sequence = seq;
    volume_.timestamp_ns = ts;
    volume_.dims = {width_, slice_rows(), count};
    volume_.type = type_;
    volume_.spacing_mm = spacing;
    volume_.voxels.assign(static_cast<std::size_t>(bytes), 0);
    assembling_ = true;
    cur_seq_ = seq;
    cur_count_ = count;
    expected_index_ = 0;
    return true;
  }

  void take_tagged(const Frame& f) {
    if (f.bytes < kSliceTagBytes) {
      push_bad_record("v4l2: frame shorter than a slice tag");
      return;
    }
    const std::uint8_t* tag = f.data;
    if (std::memcmp(tag, "USS1", 4) != 0) {
      push_bad_record("v4l2: frame without slice tag magic USS1");
      return;
    }
    const auto crc = static_cast<std::uint32_t>(::crc32(0L, tag, 28));
    if (crc != load_le<std::uint32_t>(tag + 28)) {
      push_bad_record("v4l2: slice tag crc mismatch");
      return;
    }
    const auto seq = load_le<std::uint64_t>(tag + 4);
    const int index = load_le<std::uint16_t>(tag + 12);
    const int count = load_le<std::uint16_t>(tag + 14);
    const std::array<float, 3> spacing{load_le<float>(tag + 16), load_le<float>(tag + 20), load_le<float>(tag + 24)};
    if (count == 0 || index >= count) {
      AcquireError e = make_error(AcquireError::Code::BadRecord,
                                  "v4l2: slice tag index " + std::to_string(index) + " of " + std::to_string(count));
      e.sequence = seq;
      ready_.push_back(tl::unexpected(std::move(e)));
      return;
    }
    if (f.error) return;  // a corrupt frame counts as missing: its volume turns out incomplete

    if (discarding_ && seq == discard_seq_) return;  // rest of an already reported volume
    discarding_ = false;
    if (assembling_ && (seq != cur_seq_ || index != expected_index_ || count != cur_count_)) {
      const bool same_volume = seq == cur_seq_;
      push_incomplete(cur_seq_, same_volume ? "slice " + std::to_string(expected_index_) + " missing"
                                            : "next volume started after slice " + std::to_string(expected_index_));
      assembling_ = false;
      if (same_volume) {
        discarding_ = true;
        discard_seq_ = seq;
        return;
      }
    }
    if (!assembling_) {
      if (index != 0) {
        // Joined mid-volume (start of stream, or its first slices were dropped).
        push_incomplete(seq, "first " + std::to_string(index) + " slice(s) missing");
        discarding_ = true;
        discard_seq_ = seq;
        return;
      }
      if (!start_volume(seq, count, spacing, f.timestamp_ns)) {
        discarding_ = true;
        discard_seq_ = seq;
        return;
      }
    }
    if (!copy_slice(f, 1, index)) {
      push_bad_record("v4l2: frame shorter than its format");
      return;
    }
    volume_.timestamp_ns = f.timestamp_ns;
    if (++expected_index_ == cur_count_) finish_volume();
  }

  void take_untagged(const Frame& f) {
    if (!have_untagged_base_) {
      // A (re)started stream: its frame counter starts anew, local volume numbers continue, so
      // a sequence number never names two different volumes.
      have_untagged_base_ = true;
      frame_base_ = f.driver_sequence;
      seq_base_ = next_local_seq_;
    }
    // The driver's frame counter also counts dropped frames; volume k owns frames
    // base + k*N .. base + k*N + N-1.
    const std::uint64_t rel = static_cast<std::uint32_t>(f.driver_sequence - frame_base_);
    const std::uint64_t n = static_cast<std::uint64_t>(spec_.slices);
    const std::uint64_t seq = seq_base_ + rel / n;
    next_local_seq_ = std::max(next_local_seq_, seq + 1);
    const int index = static_cast<int>(rel % n);
    if (discarding_ && seq == discard_seq_) return;
    discarding_ = false;
    if (assembling_ && (seq != cur_seq_ || index != expected_index_)) {
      const bool same_volume = seq == cur_seq_;
      push_incomplete(cur_seq_, "frame " + std::to_string(expected_index_) + " of " + std::to_string(n) + " missing");
      assembling_ = false;
      if (same_volume) {
        discarding_ = true;
        discard_seq_ = seq;
        return;
      }
    }
    if (f.error) {
      discarding_ = false;
      return;
    }
    if (!assembling_) {
      if (index != 0) {
        push_incomplete(seq, "first " + std::to_string(index) + " frame(s) missing");
        discarding_ = true;
        discard_seq_ = seq;
        return;
      }
      if (!start_volume(seq, spec_.slices, {1.0f, 1.0f, 1.0f}, f.timestamp_ns)) {
        discarding_ = true;
        discard_seq_ = seq;
        return;
      }
    }
    if (!copy_slice(f, 0, index)) {
      push_bad_record("v4l2: frame shorter than its format");
      return;
    }
    volume_.timestamp_ns = f.timestamp_ns;
    if (++expected_index_ == cur_count_) finish_volume();
  }

  struct Buffer {
    std::uint8_t* data;
    std::size_t length;
  };

  V4l2Spec spec_;
  SourceOptions options_;
  int fd_ = -1;
  int wake_fd_ = -1;
  bool streaming_ = false;
  std::vector<Buffer> buffers_;
  int width_ = 0;
  int height_ = 0;
  std::size_t stride_ = 0;
  ProbeVoxelType type_ = ProbeVoxelType::UInt8;

  std::deque<Result> ready_;
  std::atomic<bool> interrupted_{false};
  std::chrono::milliseconds backoff_{50};
  Clock::time_point next_attempt_{};

  // Slice assembly.
  RawVolume volume_;
  bool assembling_ = false;
  std::uint64_t cur_seq_ = 0;
  int cur_count_ = 0;
  int expected_index_ = 0;
  bool discarding_ = false;  // ignoring the remaining slices of an already reported volume
  std::uint64_t discard_seq_ = 0;
  bool have_untagged_base_ = false;
  std::uint32_t frame_base_ = 0;
  std::uint64_t seq_base_ = 0;        // untagged: local sequence of the stream's first volume
  std::uint64_t next_local_seq_ = 0;  // untagged: first sequence not used yet
  SequenceTracker tracker_;
};

}  // namespace

tl::expected<std::unique_ptr<Source>, AcquireError> open_v4l2_source(const std::string& target,
                                                                     const SourceOptions& options) {
  auto spec = parse_spec(target, options);
  if (!spec) return tl::unexpected(spec.error());
  auto source = std::make_unique<V4l2Source>(std::move(*spec), options);
  if (auto started = source->start(); !started) return tl::unexpected(started.error());
  return source;
}

}  // namespace sonomesh::acquire::internal
