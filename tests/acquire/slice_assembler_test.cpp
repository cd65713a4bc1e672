// SliceAssembler on plain buffers: the tagged and untagged state machine without any device.
#include "acquire/internal/slice_assembler.h"

#include <gtest/gtest.h>
#include <zlib.h>

#include <cstring>

namespace sonomesh::acquire::internal {
namespace {

using Bytes = std::vector<std::uint8_t>;
using Result = SliceAssembler::Result;

constexpr int kWidth = 40;  // >= the 32-byte tag
constexpr int kRows = 6;    // slice rows (tagged frames have one more)
constexpr std::size_t kStride = 48;

std::uint8_t pixel(std::uint64_t seq, int slice, int row, int col) {
  return static_cast<std::uint8_t>(seq * 31 + slice * 7 + row * 3 + col);
}

// One frame: (tag row if tagged) + kRows image rows of pixel(), padded to kStride.
Bytes frame_bytes(bool tagged, std::uint64_t seq, int index, int count, bool bad_crc = false) {
  const int height = kRows + (tagged ? 1 : 0);
  Bytes f(kStride * height, 0xee);
  if (tagged) {
    std::memcpy(f.data(), "USS1", 4);
    std::memcpy(f.data() + 4, &seq, 8);
    const auto i16 = static_cast<std::uint16_t>(index), n16 = static_cast<std::uint16_t>(count);
    std::memcpy(f.data() + 12, &i16, 2);
    std::memcpy(f.data() + 14, &n16, 2);
    const float spacing[3] = {0.3f, 0.4f, 0.9f};
    std::memcpy(f.data() + 16, spacing, 12);
    std::uint32_t crc = static_cast<std::uint32_t>(::crc32(0L, f.data(), 28)) ^ (bad_crc ? 1 : 0);
    std::memcpy(f.data() + 28, &crc, 4);
  }
  for (int r = 0; r < kRows; ++r) {
    for (int c = 0; c < kWidth; ++c) {
      f[kStride * (r + (tagged ? 1 : 0)) + c] = pixel(seq, index, r, c);
    }
  }
  return f;
}

class Feeder {
 public:
  explicit Feeder(int slices) : assembler_(format(slices), limits()) {}
  static SliceFormat format(int slices) {
    return {kWidth, kRows + (slices == 0 ? 1 : 0), kStride, ProbeVoxelType::UInt8, slices};
  }
  static SourceOptions limits() {
    SourceOptions o;
    o.max_dims = {1024, 1024, 16};
    return o;
  }
  // Tagged: a frame of volume `seq`, slice `index` of `count`.
  void tagged(std::uint64_t seq, int index, int count, bool error = false, bool bad_crc = false) {
    feed(frame_bytes(true, seq, index, count, bad_crc), 0, error);
  }
  // Untagged: driver frame `driver_seq`, content of local volume `seq`, slice `index`.
  void untagged(std::uint32_t driver_seq, std::uint64_t seq, int index, bool error = false) {
    feed(frame_bytes(false, seq, index, 0), driver_seq, error);
  }
  std::vector<Result> drain() {
    std::vector<Result> out;
    while (auto r = assembler_.next()) out.push_back(std::move(*r));
    return out;
  }
  SliceAssembler& assembler() { return assembler_; }

 private:
  void feed(const Bytes& bytes, std::uint32_t driver_seq, bool error) {
    Frame f{bytes.data(), bytes.size(), driver_seq, 1000u + driver_seq, error};
    assembler_.take(f);
  }
  SliceAssembler assembler_;
};

void expect_volume(const Result& r, std::uint64_t seq, int count) {
  ASSERT_TRUE(r) << to_string(r.error());
  EXPECT_EQ(r->sequence, seq);
  EXPECT_EQ(r->dims, (std::array<int, 3>{kWidth, kRows, count}));
  for (int k = 0; k < count; ++k) {
    for (int row = 0; row < kRows; ++row) {
      for (int c = 0; c < kWidth; c += 13) {
        ASSERT_EQ(r->voxels[(static_cast<std::size_t>(k) * kRows + row) * kWidth + c],
                  pixel(seq, k, row, c))
            << "slice " << k << " row " << row << " col " << c;
      }
    }
  }
}

void expect_error(const Result& r, AcquireError::Code code, std::optional<std::uint64_t> seq) {
  ASSERT_FALSE(r);
  EXPECT_EQ(r.error().code, code) << to_string(r.error());
  EXPECT_EQ(r.error().sequence, seq) << to_string(r.error());
}

TEST(SliceAssembler, TaggedSlicesMakeAVolumeBitExactDespiteTheStride) {
  Feeder feed(0);
  for (int i = 0; i < 4; ++i) feed.tagged(7, i, 4);
  const auto out = feed.drain();
  ASSERT_EQ(out.size(), 1u);
  expect_volume(out[0], 7, 4);
  EXPECT_FLOAT_EQ(out[0]->spacing_mm[2], 0.9f) << "spacing from the tag";
}

TEST(SliceAssembler, UntaggedFramesAreNumberedByTheDriversCounter) {
  Feeder feed(3);
  for (std::uint32_t f = 10; f < 16; ++f)
    feed.untagged(f, (f - 10) / 3, static_cast<int>(f - 10) % 3);
  const auto out = feed.drain();
  ASSERT_EQ(out.size(), 2u);
  expect_volume(out[0], 0, 3);
  expect_volume(out[1], 1, 3);
}

TEST(SliceAssembler, AMissingSliceSpoilsOneVolumeInBothModes) {
  Feeder tagged(0);
  tagged.tagged(0, 0, 3);
  tagged.tagged(0, 2, 3);  // slice 1 dropped
  for (int i = 0; i < 3; ++i) tagged.tagged(1, i, 3);
  auto out = tagged.drain();
  ASSERT_EQ(out.size(), 2u);
  expect_error(out[0], AcquireError::Code::Incomplete, 0);
  expect_volume(out[1], 1, 3);

  Feeder untagged(3);
  untagged.untagged(0, 0, 0);
  untagged.untagged(2, 0, 2);  // driver frame 1 dropped
  for (std::uint32_t f = 3; f < 6; ++f) untagged.untagged(f, 1, static_cast<int>(f - 3));
  out = untagged.drain();
  ASSERT_EQ(out.size(), 2u);
  expect_error(out[0], AcquireError::Code::Incomplete, 0);
  expect_volume(out[1], 1, 3);
}

TEST(SliceAssembler, AnErrorFlaggedFrameCountsAsMissing) {
  Feeder feed(0);
  feed.tagged(0, 0, 2);
  feed.tagged(0, 1, 2, /*error=*/true);
  feed.tagged(1, 0, 2);  // the next volume starts: volume 0 ends incomplete
  feed.tagged(1, 1, 2);
  const auto out = feed.drain();
  ASSERT_EQ(out.size(), 2u);
  expect_error(out[0], AcquireError::Code::Incomplete, 0);
  EXPECT_NE(out[0].error().detail.find("after slice 1"), std::string::npos);
  expect_volume(out[1], 1, 2);
}

TEST(SliceAssembler, JoiningMidVolumeAndSequenceGaps) {
  Feeder feed(0);
  feed.tagged(4, 1, 2);  // joined mid-volume
  for (int i = 0; i < 2; ++i) feed.tagged(5, i, 2);
  for (int i = 0; i < 2; ++i) feed.tagged(8, i, 2);  // 6 and 7 never came
  const auto out = feed.drain();
  ASSERT_EQ(out.size(), 4u);
  expect_error(out[0], AcquireError::Code::Incomplete, 4);
  expect_volume(out[1], 5, 2);
  expect_error(out[2], AcquireError::Code::Lost, 6);
  EXPECT_EQ(out[2].error().count, 2u);
  expect_volume(out[3], 8, 2);
}

TEST(SliceAssembler, RestartEndsTheVolumeAndUntaggedNumberingContinues) {
  Feeder feed(2);
  feed.untagged(100, 0, 0);
  feed.untagged(101, 0, 1);
  feed.untagged(102, 1, 0);
  feed.assembler().restart("link lost mid-volume", Feeder::format(2));
  feed.untagged(0, 2, 0);  // the new stream's counter starts at 0; local numbers go on
  feed.untagged(1, 2, 1);
  const auto out = feed.drain();
  ASSERT_EQ(out.size(), 3u);
  expect_volume(out[0], 0, 2);
  expect_error(out[1], AcquireError::Code::Incomplete, 1);
  EXPECT_NE(out[1].error().detail.find("link lost"), std::string::npos);
  expect_volume(out[2], 2, 2);
}

TEST(SliceAssembler, BadTagsAndOversizeVolumesAreBadRecords) {
  Feeder feed(0);
  feed.tagged(0, 0, 2, false, /*bad_crc=*/true);
  feed.tagged(1, 3, 2);   // index beyond count
  feed.tagged(2, 0, 40);  // above max_dims[2] = 16
  feed.tagged(2, 1, 40);  // the rest of a refused volume is ignored
  Bytes short_frame(10, 0);
  feed.assembler().take(Frame{short_frame.data(), short_frame.size(), 0, 0, false});
  const auto out = feed.drain();
  ASSERT_EQ(out.size(), 4u);
  expect_error(out[0], AcquireError::Code::BadRecord, std::nullopt);
  EXPECT_NE(out[0].error().detail.find("crc"), std::string::npos);
  expect_error(out[1], AcquireError::Code::BadRecord, 1);
  expect_error(out[2], AcquireError::Code::BadRecord, 2);
  expect_error(out[3], AcquireError::Code::BadRecord, std::nullopt);
}

}  // namespace
}  // namespace sonomesh::acquire::internal
