#pragma once
/// @file
/// @brief An emulated V4L2 capture device (umockdev testbed + ioctl handler) fed by test code.
///
/// The node is a regular file in the testbed (non-empty `N:` contents), so the code under test can
/// really mmap() it: REQBUFS sizes the file, DQBUF pwrite()s the next frame at the buffer's
/// offset. The process must run under libumockdev-preload (see hil_main.cpp).

#include <array>
#include <cstdint>
#include <deque>
#include <mutex>
#include <string>
#include <vector>

#include "acquire/raw_volume.h"

typedef struct _UMockdevTestbed UMockdevTestbed;
typedef struct _UMockdevIoctlBase UMockdevIoctlBase;
typedef struct _UMockdevIoctlClient UMockdevIoctlClient;

namespace sonomesh::hil {

class FakeV4l2Device {
 public:
  struct Options {
    int width = 48;
    int height = 49;   // tagged mode: row 0 holds the slice tag
    bool y16 = false;  // initial format (S_FMT may switch between GREY and Y16)
    std::string name = "video0";
  };

  explicit FakeV4l2Device(Options options);
  ~FakeV4l2Device();
  FakeV4l2Device(const FakeV4l2Device&) = delete;
  FakeV4l2Device& operator=(const FakeV4l2Device&) = delete;

  /// "/dev/video0" as the code under test sees it.
  std::string device_path() const { return "/dev/" + options_.name; }
  std::string syspath() const;
  /// Bytes of one frame in the current format (width * height * bytes per pixel).
  std::size_t frame_bytes() const;
  /// Queues one frame for the next DQBUF (must be frame_bytes() long).
  void push_frame(std::vector<std::uint8_t> frame);
  /// A frame the "hardware" lost: the driver's frame counter advances, nothing is delivered.
  void drop_frame();
  std::size_t frames_queued() const;
  std::size_t frames_delivered() const;
  bool streaming() const;

  /// Cable pulled: every ioctl fails with ENODEV, the node leaves /dev and sysfs ("remove" uevent).
  void unplug();
  /// Back again: a fresh device (no buffers, not streaming, empty frame queue).
  void replug();

 private:
  void add_device();
  static int on_ioctl(UMockdevIoctlBase* handler, UMockdevIoctlClient* client, void* self);
  bool handle_ioctl(UMockdevIoctlClient* client);
  int bytes_per_pixel() const { return y16_ ? 2 : 1; }

  Options options_;
  UMockdevTestbed* testbed_ = nullptr;
  UMockdevIoctlBase* handler_ = nullptr;
  std::string backing_path_;
  int backing_fd_ = -1;

  mutable std::mutex mutex_;
  bool y16_ = false;
  std::uint32_t buffer_count_ = 0;
  std::size_t buffer_stride_ = 0;
  std::deque<std::uint32_t> queued_buffers_;
  std::deque<std::vector<std::uint8_t>> frames_;  // a frame of {} is a dropped frame marker
  bool streaming_ = false;
  bool plugged_ = true;
  std::uint32_t frame_counter_ = 0;
  std::size_t delivered_ = 0;
};

/// The 32-byte slice tag a tagged V4L2 probe puts at the start of row 0.
std::vector<std::uint8_t> encode_slice_tag(std::uint64_t volume_sequence, int slice_index,
                                           int slice_count, const std::array<float, 3>& spacing_mm);

/// Frames a tagged probe sends for one volume: frame z = tag row + the volume's slice z
/// (width = nx, height = ny + 1). UInt16 volumes give Y16 frames.
std::vector<std::vector<std::uint8_t>> tagged_frames(const acquire::RawVolume& volume);

/// Frames an untagged probe sends: slice z of the volume as it is.
std::vector<std::vector<std::uint8_t>> untagged_frames(const acquire::RawVolume& volume);

}  // namespace sonomesh::hil
