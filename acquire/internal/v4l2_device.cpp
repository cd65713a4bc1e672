// V4l2Device: the ioctl verbs of a V4L2 MMAP capture stream.
#include "acquire/internal/v4l2_device.h"

#include <fcntl.h>
#include <linux/videodev2.h>
#include <sys/ioctl.h>
#include <sys/mman.h>
#include <unistd.h>

#include <algorithm>
#include <cerrno>
#include <cstring>

namespace sonomesh::acquire::internal {
namespace {

int xioctl(int fd, unsigned long request, void* arg) {
  int r;
  do {
    r = ::ioctl(fd, request, arg);
  } while (r == -1 && errno == EINTR);
  return r;
}

AcquireError make_error(AcquireError::Code code, std::string detail, int err = 0) {
  return AcquireError{code, err, std::move(detail), {}, 0};
}

bool is_gone(int err) { return err == ENODEV || err == ENXIO || err == EIO || err == EPIPE; }

}  // namespace

AcquireError V4l2Device::failure(const std::string& verb, int err) const {
  const auto code = is_gone(err) ? AcquireError::Code::Disconnected : AcquireError::Code::IoError;
  return make_error(code, "v4l2: " + path_ + ": " + verb + ": " + std::strerror(err), err);
}

tl::expected<void, AcquireError> V4l2Device::open(const std::string& path) {
  close();
  path_ = path;
  fd_ = ::open(path.c_str(), O_RDWR | O_NONBLOCK | O_CLOEXEC);
  if (fd_ < 0) {
    const int err = errno;
    const auto code = err == ENOENT ? AcquireError::Code::NotFound : AcquireError::Code::IoError;
    return tl::unexpected(
        make_error(code, "v4l2: cannot open " + path + ": " + std::strerror(err), err));
  }
  v4l2_capability cap{};
  if (xioctl(fd_, VIDIOC_QUERYCAP, &cap) < 0) {
    const auto e = failure("VIDIOC_QUERYCAP", errno);
    close();
    return tl::unexpected(e);
  }
  const std::uint32_t caps =
      (cap.capabilities & V4L2_CAP_DEVICE_CAPS) ? cap.device_caps : cap.capabilities;
  if (!(caps & V4L2_CAP_VIDEO_CAPTURE) || !(caps & V4L2_CAP_STREAMING)) {
    close();
    return tl::unexpected(make_error(AcquireError::Code::InvalidArgument,
                                     "v4l2: " + path + " is not a streaming video capture device"));
  }
  return {};
}

tl::expected<V4l2Device::Format, AcquireError> V4l2Device::set_format(std::uint32_t pixelformat) {
  v4l2_format fmt{};
  fmt.type = V4L2_BUF_TYPE_VIDEO_CAPTURE;
  if (xioctl(fd_, VIDIOC_G_FMT, &fmt) < 0) return tl::unexpected(failure("VIDIOC_G_FMT", errno));
  std::uint32_t want = pixelformat;
  if (want == 0) {
    want = fmt.fmt.pix.pixelformat == V4L2_PIX_FMT_Y16 ? V4L2_PIX_FMT_Y16 : V4L2_PIX_FMT_GREY;
  }
  fmt.fmt.pix.pixelformat = want;
  fmt.fmt.pix.field = V4L2_FIELD_NONE;
  fmt.fmt.pix.bytesperline = 0;  // let the driver choose its stride
  if (xioctl(fd_, VIDIOC_S_FMT, &fmt) < 0) return tl::unexpected(failure("VIDIOC_S_FMT", errno));
  if (fmt.fmt.pix.pixelformat != want) {
    return tl::unexpected(make_error(AcquireError::Code::InvalidArgument,
                                     "v4l2: " + path_ + " does not support GREY/Y16 as asked"));
  }
  Format out;
  out.width = static_cast<int>(fmt.fmt.pix.width);
  out.height = static_cast<int>(fmt.fmt.pix.height);
  out.pixelformat = want;
  const std::size_t bpp = want == V4L2_PIX_FMT_Y16 ? 2 : 1;
  out.stride = std::max<std::size_t>(fmt.fmt.pix.bytesperline,
                                     static_cast<std::size_t>(std::max(out.width, 0)) * bpp);
  return out;
}

tl::expected<void, AcquireError> V4l2Device::allocate_buffers(int count) {
  v4l2_requestbuffers req{};
  req.count = static_cast<std::uint32_t>(count);
  req.type = V4L2_BUF_TYPE_VIDEO_CAPTURE;
  req.memory = V4L2_MEMORY_MMAP;
  if (xioctl(fd_, VIDIOC_REQBUFS, &req) < 0) {
    return tl::unexpected(failure("VIDIOC_REQBUFS", errno));
  }
  if (req.count < 2) {
    return tl::unexpected(
        make_error(AcquireError::Code::IoError, "v4l2: " + path_ + ": too few buffers"));
  }
  for (std::uint32_t i = 0; i < req.count; ++i) {
    v4l2_buffer buf{};
    buf.type = V4L2_BUF_TYPE_VIDEO_CAPTURE;
    buf.memory = V4L2_MEMORY_MMAP;
    buf.index = i;
    if (xioctl(fd_, VIDIOC_QUERYBUF, &buf) < 0) {
      return tl::unexpected(failure("VIDIOC_QUERYBUF", errno));
    }
    void* p = ::mmap(nullptr, buf.length, PROT_READ | PROT_WRITE, MAP_SHARED, fd_, buf.m.offset);
    if (p == MAP_FAILED) return tl::unexpected(failure("mmap", errno));
    buffers_.push_back({static_cast<std::uint8_t*>(p), buf.length});
  }
  return {};
}

tl::expected<void, AcquireError> V4l2Device::stream_on() {
  for (std::uint32_t i = 0; i < buffers_.size(); ++i) {
    if (auto r = requeue(i); !r) return r;
  }
  int type = V4L2_BUF_TYPE_VIDEO_CAPTURE;
  if (xioctl(fd_, VIDIOC_STREAMON, &type) < 0) {
    return tl::unexpected(failure("VIDIOC_STREAMON", errno));
  }
  streaming_ = true;
  return {};
}

tl::expected<std::optional<V4l2Device::Dequeued>, AcquireError> V4l2Device::dequeue() {
  v4l2_buffer buf{};
  buf.type = V4L2_BUF_TYPE_VIDEO_CAPTURE;
  buf.memory = V4L2_MEMORY_MMAP;
  if (xioctl(fd_, VIDIOC_DQBUF, &buf) < 0) {
    if (errno == EAGAIN) return std::nullopt;
    return tl::unexpected(failure("VIDIOC_DQBUF", errno));
  }
  if (buf.index >= buffers_.size()) {
    return tl::unexpected(make_error(AcquireError::Code::IoError,
                                     "v4l2: " + path_ + ": driver returned a bad buffer index"));
  }
  const Buffer& b = buffers_[buf.index];
  Dequeued d;
  d.index = buf.index;
  d.frame.data = b.data;
  d.frame.bytes = std::min<std::size_t>(buf.bytesused ? buf.bytesused : b.length, b.length);
  d.frame.driver_sequence = buf.sequence;
  d.frame.timestamp_ns = static_cast<std::uint64_t>(buf.timestamp.tv_sec) * 1000000000ull +
                         static_cast<std::uint64_t>(buf.timestamp.tv_usec) * 1000ull;
  d.frame.error = (buf.flags & V4L2_BUF_FLAG_ERROR) != 0;
  return d;
}

tl::expected<void, AcquireError> V4l2Device::requeue(std::uint32_t index) {
  v4l2_buffer buf{};
  buf.type = V4L2_BUF_TYPE_VIDEO_CAPTURE;
  buf.memory = V4L2_MEMORY_MMAP;
  buf.index = index;
  if (xioctl(fd_, VIDIOC_QBUF, &buf) < 0) return tl::unexpected(failure("VIDIOC_QBUF", errno));
  return {};
}

void V4l2Device::close() {
  if (fd_ < 0) return;
  if (streaming_) {
    int type = V4L2_BUF_TYPE_VIDEO_CAPTURE;
    xioctl(fd_, VIDIOC_STREAMOFF, &type);
    streaming_ = false;
  }
  for (auto& b : buffers_) ::munmap(b.data, b.length);
  buffers_.clear();
  // Release the buffers (count 0) so a later open can reallocate them.
  v4l2_requestbuffers req{};
  req.type = V4L2_BUF_TYPE_VIDEO_CAPTURE;
  req.memory = V4L2_MEMORY_MMAP;
  xioctl(fd_, VIDIOC_REQBUFS, &req);
  ::close(fd_);
  fd_ = -1;
}

}  // namespace sonomesh::acquire::internal
