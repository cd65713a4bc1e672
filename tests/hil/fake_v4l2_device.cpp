#include "tests/hil/fake_v4l2_device.h"

#include <fcntl.h>
#include <linux/videodev2.h>
#include <sys/ioctl.h>
#include <umockdev.h>
#include <unistd.h>
#include <zlib.h>

#include <cerrno>
#include <cstring>
#include <memory>
#include <stdexcept>

namespace sonomesh::hil {
namespace {

std::size_t page_align(std::size_t n) {
  const std::size_t page = static_cast<std::size_t>(::sysconf(_SC_PAGESIZE));
  return (n + page - 1) / page * page;
}

void fill_pix_format(v4l2_pix_format& pix, int width, int height, bool y16) {
  pix.width = static_cast<std::uint32_t>(width);
  pix.height = static_cast<std::uint32_t>(height);
  pix.pixelformat = y16 ? V4L2_PIX_FMT_Y16 : V4L2_PIX_FMT_GREY;
  pix.field = V4L2_FIELD_NONE;
  pix.bytesperline = static_cast<std::uint32_t>(width * (y16 ? 2 : 1));
  pix.sizeimage = pix.bytesperline * static_cast<std::uint32_t>(height);
  pix.colorspace = V4L2_COLORSPACE_RAW;
}

}  // namespace

FakeV4l2Device::FakeV4l2Device(Options options) : options_(std::move(options)), y16_(options_.y16) {
  testbed_ = umockdev_testbed_new();
  add_device();
  handler_ = umockdev_ioctl_base_new();
  g_signal_connect(handler_, "handle-ioctl", G_CALLBACK(&FakeV4l2Device::on_ioctl), this);
  GError* error = nullptr;
  const std::string dev = device_path();
  if (!umockdev_testbed_attach_ioctl(testbed_, dev.c_str(), handler_, &error)) {
    std::string msg = error ? error->message : "unknown";
    g_clear_error(&error);
    throw std::runtime_error("FakeV4l2Device: attach ioctl: " + msg);
  }
}

std::string FakeV4l2Device::syspath() const {
  return "/sys/devices/platform/fakeprobe/video4linux/" + options_.name;
}

void FakeV4l2Device::add_device() {
  const std::string& n = options_.name;
  const std::string description = "P: /devices/platform/fakeprobe/video4linux/" + n +
                                  "\n"
                                  "N: " +
                                  n +
                                  "=00\n"
                                  "E: DEVNAME=/dev/" +
                                  n +
                                  "\n"
                                  "E: SUBSYSTEM=video4linux\n"
                                  "E: MAJOR=81\n"
                                  "E: MINOR=0\n"
                                  "A: dev=81:0\n"
                                  "A: name=Fake 3D Probe\n"
                                  "A: index=0\n";
  GError* error = nullptr;
  if (!umockdev_testbed_add_from_string(testbed_, description.c_str(), &error)) {
    std::string msg = error ? error->message : "unknown";
    g_clear_error(&error);
    throw std::runtime_error("FakeV4l2Device: add device: " + msg);
  }
  // The root directory string is the caller's to free (transfer full).
  std::unique_ptr<gchar, decltype(&g_free)> root(umockdev_testbed_get_root_dir(testbed_), g_free);
  backing_path_ = std::string(root.get()) + "/dev/" + n;
  if (backing_fd_ >= 0) ::close(backing_fd_);
  backing_fd_ = ::open(backing_path_.c_str(), O_RDWR | O_CLOEXEC);
  if (backing_fd_ < 0)
    throw std::runtime_error("FakeV4l2Device: open backing file " + backing_path_);
}

void FakeV4l2Device::unplug() {
  {
    std::lock_guard lock(mutex_);
    if (!plugged_) return;
    plugged_ = false;
    streaming_ = false;
    buffer_count_ = 0;
    queued_buffers_.clear();
    frames_.clear();
  }
  umockdev_testbed_uevent(testbed_, syspath().c_str(), "remove");
  umockdev_testbed_remove_device(testbed_, syspath().c_str());
}

void FakeV4l2Device::replug() {
  {
    std::lock_guard lock(mutex_);
    if (plugged_) return;
  }
  add_device();
  const std::string dev = device_path();
  umockdev_testbed_detach_ioctl(testbed_, dev.c_str(), nullptr);
  GError* error = nullptr;
  if (!umockdev_testbed_attach_ioctl(testbed_, dev.c_str(), handler_, &error)) {
    std::string msg = error ? error->message : "unknown";
    g_clear_error(&error);
    throw std::runtime_error("FakeV4l2Device: re-attach ioctl: " + msg);
  }
  {
    std::lock_guard lock(mutex_);
    plugged_ = true;
    frame_counter_ = 0;
  }
  umockdev_testbed_uevent(testbed_, syspath().c_str(), "add");
}

FakeV4l2Device::~FakeV4l2Device() {
  const std::string dev = device_path();
  umockdev_testbed_detach_ioctl(testbed_, dev.c_str(), nullptr);
  g_object_unref(handler_);
  if (backing_fd_ >= 0) ::close(backing_fd_);
  g_object_unref(testbed_);
}

std::size_t FakeV4l2Device::frame_bytes() const {
  std::lock_guard lock(mutex_);
  return static_cast<std::size_t>(options_.width) * static_cast<std::size_t>(options_.height) *
         static_cast<std::size_t>(bytes_per_pixel());
}

void FakeV4l2Device::push_frame(std::vector<std::uint8_t> frame) {
  if (frame.size() != frame_bytes())
    throw std::invalid_argument("FakeV4l2Device::push_frame: wrong frame size");
  std::lock_guard lock(mutex_);
  frames_.push_back(std::move(frame));
}

void FakeV4l2Device::drop_frame() {
  std::lock_guard lock(mutex_);
  frames_.emplace_back();
}

std::size_t FakeV4l2Device::frames_queued() const {
  std::lock_guard lock(mutex_);
  return frames_.size();
}

std::size_t FakeV4l2Device::frames_delivered() const {
  std::lock_guard lock(mutex_);
  return delivered_;
}

bool FakeV4l2Device::streaming() const {
  std::lock_guard lock(mutex_);
  return streaming_;
}

int FakeV4l2Device::on_ioctl(UMockdevIoctlBase*, UMockdevIoctlClient* client, void* self) {
  return static_cast<FakeV4l2Device*>(self)->handle_ioctl(client) ? TRUE : FALSE;
}

bool FakeV4l2Device::handle_ioctl(UMockdevIoctlClient* client) {
  const unsigned long request = umockdev_ioctl_client_get_request(client);
  UMockdevIoctlData* arg = umockdev_ioctl_client_get_arg(client);
  const std::size_t size = _IOC_SIZE(request);
  UMockdevIoctlData* data = nullptr;
  if (size > 0) {
    GError* error = nullptr;
    data = umockdev_ioctl_data_resolve(arg, 0, size, &error);
    if (!data) {
      g_clear_error(&error);
      umockdev_ioctl_client_complete(client, -1, EFAULT);
      return true;
    }
  }
  long result = 0;
  int err = 0;
  {
    std::lock_guard lock(mutex_);
    if (!plugged_) {
      result = -1;
      err = ENODEV;  // what a driver answers after its device went away
    } else
      switch (request) {
        case VIDIOC_QUERYCAP: {
          auto* cap = reinterpret_cast<v4l2_capability*>(data->data);
          std::memset(cap, 0, sizeof *cap);
          std::strncpy(reinterpret_cast<char*>(cap->driver), "fakeprobe", sizeof cap->driver - 1);
          std::strncpy(reinterpret_cast<char*>(cap->card), "Fake 3D Probe", sizeof cap->card - 1);
          std::strncpy(reinterpret_cast<char*>(cap->bus_info), "platform:fakeprobe",
                       sizeof cap->bus_info - 1);
          cap->version = 0x060000;
          cap->device_caps = V4L2_CAP_VIDEO_CAPTURE | V4L2_CAP_STREAMING;
          cap->capabilities = cap->device_caps | V4L2_CAP_DEVICE_CAPS;
          break;
        }
        case VIDIOC_ENUM_FMT: {
          auto* f = reinterpret_cast<v4l2_fmtdesc*>(data->data);
          if (f->type != V4L2_BUF_TYPE_VIDEO_CAPTURE || f->index > 1) {
            result = -1;
            err = EINVAL;
            break;
          }
          f->pixelformat = f->index == 0 ? V4L2_PIX_FMT_GREY : V4L2_PIX_FMT_Y16;
          std::strncpy(reinterpret_cast<char*>(f->description),
                       f->index == 0 ? "8-bit Greyscale" : "16-bit Greyscale",
                       sizeof f->description - 1);
          break;
        }
        case VIDIOC_G_FMT:
        case VIDIOC_S_FMT:
        case VIDIOC_TRY_FMT: {
          auto* f = reinterpret_cast<v4l2_format*>(data->data);
          if (f->type != V4L2_BUF_TYPE_VIDEO_CAPTURE) {
            result = -1;
            err = EINVAL;
            break;
          }
          bool y16 = y16_;
          if (request != VIDIOC_G_FMT) {
            y16 = f->fmt.pix.pixelformat == V4L2_PIX_FMT_Y16;  // anything else falls back to GREY
            if (request == VIDIOC_S_FMT) {
              if (buffer_count_ > 0) {
                result = -1;
                err = EBUSY;
                break;
              }
              y16_ = y16;
            }
          }
          fill_pix_format(f->fmt.pix, options_.width, options_.height, y16);
          break;
        }
        case VIDIOC_REQBUFS: {
          auto* req = reinterpret_cast<v4l2_requestbuffers*>(data->data);
          if (req->type != V4L2_BUF_TYPE_VIDEO_CAPTURE || req->memory != V4L2_MEMORY_MMAP ||
              streaming_) {
            result = -1;
            err = streaming_ ? EBUSY : EINVAL;
            break;
          }
          const std::size_t image = static_cast<std::size_t>(options_.width) *
                                    static_cast<std::size_t>(options_.height) *
                                    static_cast<std::size_t>(bytes_per_pixel());
          buffer_count_ = std::min<std::uint32_t>(req->count, 8);
          buffer_stride_ = page_align(image);
          queued_buffers_.clear();
          if (::ftruncate(backing_fd_,
                          static_cast<off_t>(buffer_stride_ *
                                             std::max<std::uint32_t>(buffer_count_, 1))) != 0) {
            result = -1;
            err = ENOMEM;
            break;
          }
          req->count = buffer_count_;
          req->capabilities = V4L2_BUF_CAP_SUPPORTS_MMAP;
          break;
        }
        case VIDIOC_QUERYBUF:
        case VIDIOC_QBUF: {
          auto* buf = reinterpret_cast<v4l2_buffer*>(data->data);
          if (buf->type != V4L2_BUF_TYPE_VIDEO_CAPTURE || buf->index >= buffer_count_) {
            result = -1;
            err = EINVAL;
            break;
          }
          if (request == VIDIOC_QBUF) queued_buffers_.push_back(buf->index);
          buf->memory = V4L2_MEMORY_MMAP;
          buf->length = static_cast<std::uint32_t>(buffer_stride_);
          buf->m.offset = static_cast<std::uint32_t>(buf->index * buffer_stride_);
          buf->flags = V4L2_BUF_FLAG_MAPPED | (request == VIDIOC_QBUF ? V4L2_BUF_FLAG_QUEUED : 0);
          break;
        }
        case VIDIOC_DQBUF: {
          auto* buf = reinterpret_cast<v4l2_buffer*>(data->data);
          if (!streaming_) {
            result = -1;
            err = EINVAL;
            break;
          }
          // Dropped-frame markers only advance the frame counter, like a driver that lost a frame.
          while (!frames_.empty() && frames_.front().empty()) {
            frames_.pop_front();
            ++frame_counter_;
          }
          if (frames_.empty() || queued_buffers_.empty()) {
            result = -1;
            err = EAGAIN;  // the node is opened O_NONBLOCK by the code under test
            break;
          }
          const std::uint32_t index = queued_buffers_.front();
          queued_buffers_.pop_front();
          const std::vector<std::uint8_t> frame = std::move(frames_.front());
          frames_.pop_front();
          const off_t offset = static_cast<off_t>(index * buffer_stride_);
          if (::pwrite(backing_fd_, frame.data(), frame.size(), offset) !=
              static_cast<ssize_t>(frame.size())) {
            result = -1;
            err = EIO;
            break;
          }
          timespec now{};
          ::clock_gettime(CLOCK_MONOTONIC, &now);
          buf->index = index;
          buf->memory = V4L2_MEMORY_MMAP;
          buf->bytesused = static_cast<std::uint32_t>(frame.size());
          buf->length = static_cast<std::uint32_t>(buffer_stride_);
          buf->m.offset = static_cast<std::uint32_t>(offset);
          buf->flags =
              V4L2_BUF_FLAG_MAPPED | V4L2_BUF_FLAG_DONE | V4L2_BUF_FLAG_TIMESTAMP_MONOTONIC;
          buf->field = V4L2_FIELD_NONE;
          buf->sequence = frame_counter_++;
          buf->timestamp.tv_sec = now.tv_sec;
          buf->timestamp.tv_usec = now.tv_nsec / 1000;
          ++delivered_;
          break;
        }
        case VIDIOC_STREAMON:
        case VIDIOC_STREAMOFF: {
          const int type = *reinterpret_cast<int*>(data->data);
          if (type != V4L2_BUF_TYPE_VIDEO_CAPTURE || buffer_count_ == 0) {
            result = -1;
            err = EINVAL;
            break;
          }
          streaming_ = request == VIDIOC_STREAMON;
          if (!streaming_) queued_buffers_.clear();
          break;
        }
        default:
          result = -1;
          err = ENOTTY;
          break;
      }
  }
  umockdev_ioctl_client_complete(client, result, err);
  if (data) g_object_unref(data);
  return true;
}

std::vector<std::uint8_t> encode_slice_tag(std::uint64_t volume_sequence, int slice_index,
                                           int slice_count,
                                           const std::array<float, 3>& spacing_mm) {
  std::vector<std::uint8_t> tag(32, 0);
  std::memcpy(tag.data(), "USS1", 4);
  std::memcpy(tag.data() + 4, &volume_sequence, 8);
  const auto index = static_cast<std::uint16_t>(slice_index);
  const auto count = static_cast<std::uint16_t>(slice_count);
  std::memcpy(tag.data() + 12, &index, 2);
  std::memcpy(tag.data() + 14, &count, 2);
  std::memcpy(tag.data() + 16, spacing_mm.data(), 12);
  const auto crc = static_cast<std::uint32_t>(::crc32(0L, tag.data(), 28));
  std::memcpy(tag.data() + 28, &crc, 4);
  return tag;
}

std::vector<std::vector<std::uint8_t>> tagged_frames(const acquire::RawVolume& volume) {
  const auto [nx, ny, nz] = volume.dims;
  const std::size_t bpp = static_cast<std::size_t>(acquire::bytes_per_voxel(volume.type));
  const std::size_t row = static_cast<std::size_t>(nx) * bpp;
  const std::size_t slice = row * static_cast<std::size_t>(ny);
  std::vector<std::vector<std::uint8_t>> frames;
  for (int z = 0; z < nz; ++z) {
    std::vector<std::uint8_t> f(row + slice, 0);
    const auto tag = encode_slice_tag(volume.sequence, z, nz, volume.spacing_mm);
    std::memcpy(f.data(), tag.data(), std::min(tag.size(), row));
    std::memcpy(f.data() + row, volume.voxels.data() + static_cast<std::size_t>(z) * slice, slice);
    frames.push_back(std::move(f));
  }
  return frames;
}

std::vector<std::vector<std::uint8_t>> untagged_frames(const acquire::RawVolume& volume) {
  const auto [nx, ny, nz] = volume.dims;
  const std::size_t slice = static_cast<std::size_t>(nx) * static_cast<std::size_t>(ny) *
                            static_cast<std::size_t>(acquire::bytes_per_voxel(volume.type));
  std::vector<std::vector<std::uint8_t>> frames;
  for (int z = 0; z < nz; ++z) {
    const auto* p = volume.voxels.data() + static_cast<std::size_t>(z) * slice;
    frames.emplace_back(p, p + slice);
  }
  return frames;
}

}  // namespace sonomesh::hil
