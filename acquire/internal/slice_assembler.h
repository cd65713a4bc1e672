#pragma once
/// @file
/// @brief V4L2 frames -> volumes: the slice assembly of frame-grabber probes, free of any ioctl
/// (internal; unit-tested on plain buffers).
///
/// Tagged mode: row 0 of every frame starts with a 32-byte slice tag (magic "USS1", u64 volume
/// sequence, u16 slice index, u16 slice count, 3 x f32 spacing_mm, u32 crc32 of bytes 0..27);
/// the slice image is rows 1..H-1. Untagged mode: N consecutive frames are one volume, aligned on
/// the driver's frame counter so that a dropped frame spoils only the volume it belonged to.
/// Both modes name each frame (volume sequence, slice index, slice count) and share one state
/// machine from there.

#include <array>
#include <cstddef>
#include <cstdint>
#include <deque>
#include <string>

#include "acquire/acquire.h"
#include "acquire/protocol.h"

namespace sonomesh::acquire::internal {

constexpr std::size_t kSliceTagBytes = 32;

/// The frame format the device agreed to.
struct SliceFormat {
  int width = 0;
  int height = 0;          // frame rows, the tag row included
  std::size_t stride = 0;  // bytes per row
  ProbeVoxelType type = ProbeVoxelType::UInt8;
  int slices = 0;  // frames per volume; 0 = tagged mode
};

/// One dequeued frame, borrowed from the driver's buffer.
struct Frame {
  const std::uint8_t* data = nullptr;
  std::size_t bytes = 0;
  std::uint32_t driver_sequence = 0;  // the driver's frame counter (counts dropped frames too)
  std::uint64_t timestamp_ns = 0;
  bool error = false;  // V4L2_BUF_FLAG_ERROR: the frame counts as missing
};

class SliceAssembler {
 public:
  using Result = tl::expected<RawVolume, AcquireError>;

  /// `limits`: max_dims[2] and max_payload_bytes bound a volume before it is allocated.
  SliceAssembler(SliceFormat format, const SourceOptions& limits);

  /// Takes one frame; results (volumes, Lost, Incomplete, BadRecord) queue up for next().
  void take(const Frame& frame);
  /// A new stream began (device reopened, maybe with another format): the driver's counter
  /// starts anew and a volume in progress can no longer complete (reported Incomplete, `why`).
  /// Sequence numbering and gap tracking continue.
  void restart(const std::string& why, const SliceFormat& format);
  /// The next queued result, if any.
  std::optional<Result> next();

  const SliceFormat& format() const { return format_; }

 private:
  struct Slot {  // where a frame belongs
    std::uint64_t sequence = 0;
    int index = 0;
    int count = 0;
    std::array<float, 3> spacing_mm{1.0f, 1.0f, 1.0f};
  };
  bool tagged() const { return format_.slices == 0; }
  int slice_rows() const { return tagged() ? format_.height - 1 : format_.height; }
  std::size_t slice_bytes() const;

  std::optional<Slot> slot_of_tagged(const Frame& frame);
  Slot slot_of_untagged(const Frame& frame);
  void place(const Slot& slot, const Frame& frame);
  bool start_volume(const Slot& slot, std::uint64_t timestamp_ns);
  bool copy_slice(const Frame& frame, int index);
  void finish_volume();
  void discard(std::uint64_t sequence);
  void push_incomplete(std::uint64_t sequence, const std::string& why);
  void push_bad_record(std::string detail, std::optional<std::uint64_t> sequence = {});
  void note_sequence(std::uint64_t sequence);

  SliceFormat format_;
  int max_slices_;
  std::uint64_t max_payload_bytes_;
  std::deque<Result> ready_;
  SequenceTracker tracker_;

  RawVolume volume_;
  bool assembling_ = false;
  int expected_index_ = 0;
  bool discarding_ = false;  // ignoring the remaining slices of an already reported volume
  std::uint64_t discard_sequence_ = 0;
  // Untagged numbering: volume k of a stream owns frames base + k*N .. base + k*N + N-1.
  bool have_frame_base_ = false;
  std::uint32_t frame_base_ = 0;
  std::uint64_t sequence_base_ = 0;  // local sequence of the stream's first volume
  std::uint64_t next_sequence_ = 0;  // first local sequence not used yet
};

}  // namespace sonomesh::acquire::internal
