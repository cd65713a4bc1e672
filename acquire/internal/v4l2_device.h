#pragma once
/// @file
/// @brief A V4L2 capture device in a few verbs (after libcamera's V4L2VideoDevice): open,
/// set_format, allocate_buffers, stream_on, dequeue/requeue, close (internal).
///
/// Plain libc open/ioctl/mmap streaming (no libv4l2: it issues raw syscalls that neither
/// LD_PRELOAD-based emulation nor some sandboxes see, and GREY/Y16 need no conversion).

#include <cstdint>
#include <optional>
#include <string>
#include <tl/expected.hpp>
#include <vector>

#include "acquire/acquire.h"
#include "acquire/internal/slice_assembler.h"

namespace sonomesh::acquire::internal {

class V4l2Device {
 public:
  struct Format {
    int width = 0;
    int height = 0;
    std::size_t stride = 0;         // bytes per row
    std::uint32_t pixelformat = 0;  // V4L2_PIX_FMT_GREY or _Y16
  };
  struct Dequeued {
    Frame frame;  // borrows the buffer until requeue(index)
    std::uint32_t index = 0;
  };

  V4l2Device() = default;
  ~V4l2Device() { close(); }
  V4l2Device(const V4l2Device&) = delete;
  V4l2Device& operator=(const V4l2Device&) = delete;

  /// Opens the node (non-blocking) and checks it is a streaming capture device.
  tl::expected<void, AcquireError> open(const std::string& path);
  /// Sets GREY or Y16 (`pixelformat` 0: keep Y16 if current, else GREY), progressive.
  tl::expected<Format, AcquireError> set_format(std::uint32_t pixelformat);
  /// Requests and maps `count` MMAP buffers (at least 2).
  tl::expected<void, AcquireError> allocate_buffers(int count);
  /// Queues every buffer and starts streaming.
  tl::expected<void, AcquireError> stream_on();
  /// The next filled buffer; nullopt if none is ready yet (poll() may report ready without one).
  /// Disconnected if the device went away.
  tl::expected<std::optional<Dequeued>, AcquireError> dequeue();
  /// Gives a dequeued buffer back to the driver.
  tl::expected<void, AcquireError> requeue(std::uint32_t index);
  /// Stops streaming, unmaps and releases the buffers, closes the node. Idempotent.
  void close();

  int fd() const { return fd_; }
  bool is_open() const { return fd_ >= 0; }
  const std::string& path() const { return path_; }

 private:
  struct Buffer {
    std::uint8_t* data = nullptr;
    std::size_t length = 0;
  };
  AcquireError failure(const std::string& verb, int err) const;

  std::string path_;
  int fd_ = -1;
  bool streaming_ = false;
  std::vector<Buffer> buffers_;
};

}  // namespace sonomesh::acquire::internal
