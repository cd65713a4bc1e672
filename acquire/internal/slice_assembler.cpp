// SliceAssembler: one state machine for tagged and untagged V4L2 slice streams.
#include "acquire/internal/slice_assembler.h"

#include <zlib.h>

#include <algorithm>
#include <cstring>

namespace sonomesh::acquire::internal {
namespace {

template <typename T>
T load_le(const std::uint8_t* p) {
  T v;
  std::memcpy(&v, p, sizeof v);  // host is little endian (x86-64/aarch64), as is the tag
  return v;
}

AcquireError make_error(AcquireError::Code code, std::string detail,
                        std::optional<std::uint64_t> sequence = {}) {
  return AcquireError{code, 0, std::move(detail), sequence, 0};
}

}  // namespace

SliceAssembler::SliceAssembler(SliceFormat format, const SourceOptions& limits)
    : format_(format),
      max_slices_(limits.max_dims[2]),
      max_payload_bytes_(limits.max_payload_bytes) {}

std::size_t SliceAssembler::slice_bytes() const {
  return static_cast<std::size_t>(format_.width) * static_cast<std::size_t>(slice_rows()) *
         static_cast<std::size_t>(bytes_per_voxel(format_.type));
}

std::optional<SliceAssembler::Result> SliceAssembler::next() {
  if (ready_.empty()) return std::nullopt;
  Result r = std::move(ready_.front());
  ready_.pop_front();
  return r;
}

void SliceAssembler::take(const Frame& frame) {
  if (tagged()) {
    if (auto slot = slot_of_tagged(frame)) place(*slot, frame);
  } else {
    place(slot_of_untagged(frame), frame);
  }
}

void SliceAssembler::restart(const std::string& why, const SliceFormat& format) {
  if (assembling_) push_incomplete(volume_.sequence, why);
  format_ = format;
  assembling_ = false;
  discarding_ = false;
  have_frame_base_ = false;
  expected_index_ = 0;
}

std::optional<SliceAssembler::Slot> SliceAssembler::slot_of_tagged(const Frame& f) {
  if (f.bytes < kSliceTagBytes) {
    push_bad_record("v4l2: frame shorter than a slice tag");
    return std::nullopt;
  }
  const std::uint8_t* tag = f.data;
  if (std::memcmp(tag, "USS1", 4) != 0) {
    push_bad_record("v4l2: frame without slice tag magic USS1");
    return std::nullopt;
  }
  if (static_cast<std::uint32_t>(::crc32(0L, tag, 28)) != load_le<std::uint32_t>(tag + 28)) {
    push_bad_record("v4l2: slice tag crc mismatch");
    return std::nullopt;
  }
  Slot s;
  s.sequence = load_le<std::uint64_t>(tag + 4);
  s.index = load_le<std::uint16_t>(tag + 12);
  s.count = load_le<std::uint16_t>(tag + 14);
  s.spacing_mm = {load_le<float>(tag + 16), load_le<float>(tag + 20), load_le<float>(tag + 24)};
  if (s.count == 0 || s.index >= s.count) {
    push_bad_record(
        "v4l2: slice tag index " + std::to_string(s.index) + " of " + std::to_string(s.count),
        s.sequence);
    return std::nullopt;
  }
  return s;
}

SliceAssembler::Slot SliceAssembler::slot_of_untagged(const Frame& f) {
  if (!have_frame_base_) {
    // A (re)started stream: its frame counter starts anew, local volume numbers continue, so
    // a sequence number never names two different volumes.
    have_frame_base_ = true;
    frame_base_ = f.driver_sequence;
    sequence_base_ = next_sequence_;
  }
  const std::uint64_t relative = static_cast<std::uint32_t>(f.driver_sequence - frame_base_);
  const auto n = static_cast<std::uint64_t>(format_.slices);
  Slot s;
  s.sequence = sequence_base_ + relative / n;
  s.index = static_cast<int>(relative % n);
  s.count = format_.slices;
  next_sequence_ = std::max(next_sequence_, s.sequence + 1);
  return s;
}

// The state machine: a volume is assembled from slice 0 to count-1 in order; the first slice
// out of order ends it as Incomplete, and the rest of a reported volume is ignored.
void SliceAssembler::place(const Slot& slot, const Frame& frame) {
  if (discarding_ && slot.sequence == discard_sequence_) return;
  discarding_ = false;
  if (assembling_ && (slot.sequence != volume_.sequence || slot.index != expected_index_ ||
                      slot.count != volume_.dims[2])) {
    const bool same_volume = slot.sequence == volume_.sequence;
    push_incomplete(volume_.sequence,
                    same_volume
                        ? "slice " + std::to_string(expected_index_) + " missing"
                        : "next volume started after slice " + std::to_string(expected_index_));
    assembling_ = false;
    if (same_volume) return discard(slot.sequence);
  }
  if (frame.error) return;  // a corrupt frame counts as missing: its volume turns out incomplete
  if (!assembling_) {
    if (slot.index != 0) {
      // Joined mid-volume (start of stream, or its first slices were dropped).
      push_incomplete(slot.sequence, "first " + std::to_string(slot.index) + " slice(s) missing");
      return discard(slot.sequence);
    }
    if (!start_volume(slot, frame.timestamp_ns)) return discard(slot.sequence);
  }
  if (!copy_slice(frame, slot.index)) {
    push_bad_record("v4l2: frame shorter than its format");
    return;
  }
  volume_.timestamp_ns = frame.timestamp_ns;
  if (++expected_index_ == volume_.dims[2]) finish_volume();
}

bool SliceAssembler::start_volume(const Slot& slot, std::uint64_t timestamp_ns) {
  const std::uint64_t bytes =
      static_cast<std::uint64_t>(slice_bytes()) * static_cast<std::uint64_t>(slot.count);
  if (slot.count > max_slices_ || bytes > max_payload_bytes_) {
    push_bad_record("v4l2: volume " + std::to_string(slot.sequence) + " with " +
                        std::to_string(slot.count) + " slices exceeds the configured limits",
                    slot.sequence);
    return false;
  }
  volume_ = RawVolume{};
  volume_.sequence = slot.sequence;
  volume_.timestamp_ns = timestamp_ns;
  volume_.dims = {format_.width, slice_rows(), slot.count};
  volume_.type = format_.type;
  volume_.spacing_mm = slot.spacing_mm;
  volume_.voxels.assign(static_cast<std::size_t>(bytes), 0);
  assembling_ = true;
  expected_index_ = 0;
  return true;
}

// Copies the slice rows (tagged: rows 1..H-1) of the frame into slice `index` of the volume.
bool SliceAssembler::copy_slice(const Frame& f, int index) {
  const std::size_t row_bytes = static_cast<std::size_t>(format_.width) *
                                static_cast<std::size_t>(bytes_per_voxel(format_.type));
  const std::size_t needed =
      format_.stride * static_cast<std::size_t>(format_.height - 1) + row_bytes;
  if (f.bytes < needed) return false;
  std::uint8_t* dst = volume_.voxels.data() + static_cast<std::size_t>(index) * slice_bytes();
  for (int r = tagged() ? 1 : 0; r < format_.height; ++r, dst += row_bytes) {
    std::memcpy(dst, f.data + static_cast<std::size_t>(r) * format_.stride, row_bytes);
  }
  return true;
}

void SliceAssembler::finish_volume() {
  volume_.received = std::chrono::steady_clock::now();
  note_sequence(volume_.sequence);
  ready_.push_back(std::move(volume_));
  volume_ = RawVolume{};
  assembling_ = false;
}

void SliceAssembler::discard(std::uint64_t sequence) {
  discarding_ = true;
  discard_sequence_ = sequence;
}

void SliceAssembler::push_incomplete(std::uint64_t sequence, const std::string& why) {
  // The volume was seen (just not whole): it must not later count as lost.
  note_sequence(sequence);
  ready_.push_back(tl::unexpected(
      make_error(AcquireError::Code::Incomplete,
                 "v4l2: volume " + std::to_string(sequence) + " incomplete: " + why, sequence)));
}

void SliceAssembler::push_bad_record(std::string detail, std::optional<std::uint64_t> sequence) {
  ready_.push_back(
      tl::unexpected(make_error(AcquireError::Code::BadRecord, std::move(detail), sequence)));
}

// A gap before `sequence` is reported as Lost before the volume.
void SliceAssembler::note_sequence(std::uint64_t sequence) {
  if (auto gap = tracker_.observe_volume(sequence)) {
    AcquireError e = make_error(AcquireError::Code::Lost,
                                "v4l2: " + std::to_string(gap->count) +
                                    " volume(s) missing before " + std::to_string(sequence),
                                gap->first_missing);
    e.count = gap->count;
    ready_.push_back(tl::unexpected(std::move(e)));
  }
}

}  // namespace sonomesh::acquire::internal
