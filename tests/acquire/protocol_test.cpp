// Probe stream protocol v1: round trips, every corruption class, resync, limits, gaps.
#include <gtest/gtest.h>

#include <atomic>
#include <cstdlib>
#include <cstring>
#include <new>
#include <random>

#include "acquire/internal/stream_decoder.h"
#include "test_util.h"

// The replacement operator delete pairs with the replacement operator new (both malloc/free).
#pragma GCC diagnostic ignored "-Wmismatched-new-delete"

// Largest single allocation while tracking is on: proves the parser sizes nothing from a header.
namespace {
std::atomic<bool> g_track{false};
std::atomic<std::size_t> g_largest{0};
}  // namespace
void* operator new(std::size_t size) {
  if (g_track.load(std::memory_order_relaxed)) {
    std::size_t prev = g_largest.load();
    while (size > prev && !g_largest.compare_exchange_weak(prev, size)) {
    }
  }
  if (void* p = std::malloc(size == 0 ? 1 : size)) return p;
  throw std::bad_alloc();
}
void operator delete(void* p) noexcept { std::free(p); }
void operator delete(void* p, std::size_t) noexcept { std::free(p); }

namespace sonomesh::acquire {
namespace {

using test::append;
using test::make_volume;
using test::record;

std::vector<ParserEvent> drain(StreamParser& parser) {
  std::vector<ParserEvent> events;
  while (auto e = parser.next_event()) events.push_back(std::move(*e));
  return events;
}

std::vector<ParserEvent> parse_all(const std::vector<std::uint8_t>& bytes, std::size_t chunk,
                                   ParserLimits limits = {}) {
  StreamParser parser(limits);
  std::vector<ParserEvent> events;
  for (std::size_t i = 0; i < bytes.size(); i += chunk) {
    parser.feed(bytes.data() + i, std::min(chunk, bytes.size() - i));
    auto more = drain(parser);
    for (auto& e : more) events.push_back(std::move(e));
  }
  parser.finish();
  for (auto& e : drain(parser)) events.push_back(std::move(e));
  return events;
}

void expect_same(const RawVolume& a, const RawVolume& b) {
  EXPECT_EQ(a.sequence, b.sequence);
  EXPECT_EQ(a.timestamp_ns, b.timestamp_ns);
  EXPECT_EQ(a.dims, b.dims);
  EXPECT_EQ(a.type, b.type);
  EXPECT_EQ(a.spacing_mm, b.spacing_mm);
  EXPECT_EQ(a.origin_mm, b.origin_mm);
  EXPECT_TRUE(a.voxels == b.voxels);
}

class RoundTrip : public ::testing::TestWithParam<ProbeVoxelType> {};

TEST_P(RoundTrip, VolumesSurviveAnyChunking) {
  std::vector<RawVolume> sent;
  std::vector<std::uint8_t> stream;
  for (std::uint64_t s = 0; s < 4; ++s) {
    sent.push_back(make_volume(s, {33, 17, 9}, GetParam()));
    append(stream, record(sent.back()));
  }
  append(stream, encode_heartbeat(4, 77));
  append(stream, encode_end_of_stream(4, 78));
  for (std::size_t chunk : {std::size_t{1}, std::size_t{7}, std::size_t{4096}, stream.size()}) {
    const auto events = parse_all(stream, chunk);
    ASSERT_EQ(events.size(), 6u) << "chunk " << chunk;
    for (int i = 0; i < 4; ++i) {
      ASSERT_TRUE(std::holds_alternative<RawVolume>(events[i]));
      const auto& got = std::get<RawVolume>(events[i]);
      expect_same(got, sent[i]);
      EXPECT_EQ(record(got), record(sent[i])) << "re-encoding must give the received bytes";
    }
    ASSERT_TRUE(std::holds_alternative<Heartbeat>(events[4]));
    EXPECT_EQ(std::get<Heartbeat>(events[4]).next_sequence, 4u);
    EXPECT_EQ(std::get<Heartbeat>(events[4]).timestamp_ns, 77u);
    ASSERT_TRUE(std::holds_alternative<EndOfStream>(events[5]));
    EXPECT_EQ(std::get<EndOfStream>(events[5]).timestamp_ns, 78u);
  }
}

INSTANTIATE_TEST_SUITE_P(VoxelTypes, RoundTrip,
                         ::testing::Values(ProbeVoxelType::UInt8, ProbeVoxelType::UInt16));

TEST(Protocol, HeaderLayoutMatchesTheSpec) {
  const RawVolume v = make_volume(0x0102030405060708ull, {3, 4, 5}, ProbeVoxelType::UInt16);
  const auto bytes = record(v);
  ASSERT_EQ(bytes.size(), 64u + 3 * 4 * 5 * 2 + 4);
  EXPECT_EQ(std::memcmp(bytes.data(), "USV1", 4), 0);
  EXPECT_EQ(bytes[4], 1);  // version, little endian
  EXPECT_EQ(bytes[5], 0);
  EXPECT_EQ(bytes[6], 1);  // kind volume
  EXPECT_EQ(bytes[8], 0x08);
  EXPECT_EQ(bytes[15], 0x01);
  EXPECT_EQ(bytes[24], 3);
  EXPECT_EQ(bytes[26], 4);
  EXPECT_EQ(bytes[28], 5);
  EXPECT_EQ(bytes[30], 2);  // uint16
  EXPECT_EQ(bytes[31], 0);
  float sx = 0;
  std::memcpy(&sx, &bytes[32], 4);
  EXPECT_EQ(sx, 0.5f);
  EXPECT_EQ(bytes[56], 120);  // payload_bytes
  EXPECT_EQ(decode_header(bytes.data()).header_crc32, crc32(bytes.data(), 60));
  const std::uint32_t payload_crc = crc32(bytes.data() + 64, 120);
  std::uint32_t stored = 0;
  std::memcpy(&stored, bytes.data() + 184, 4);
  EXPECT_EQ(stored, payload_crc);
  EXPECT_EQ(encode_heartbeat(1, 2).size(), 68u);
}

TEST(Protocol, Crc32IsZlibIeee) {
  const char* text = "123456789";
  EXPECT_EQ(crc32(reinterpret_cast<const std::uint8_t*>(text), 9), 0xCBF43926u);
  EXPECT_EQ(crc32(nullptr, 0), 0u);
}

TEST(Protocol, EncodeRefusesInconsistentVolumes) {
  RawVolume v = make_volume(1, {4, 4, 4});
  v.voxels.pop_back();
  EXPECT_FALSE(encode_volume_record(v));
  v = make_volume(1, {4, 4, 4});
  v.dims = {0, 4, 4};
  EXPECT_FALSE(encode_volume_record(v));
  v.dims = {70000, 1, 1};
  EXPECT_FALSE(encode_volume_record(v));
}

// A header rewritten with a valid CRC (so the reader trusts and then refuses it).
std::vector<std::uint8_t> with_header(std::vector<std::uint8_t> rec,
                                      const std::function<void(RecordHeader&)>& change) {
  RecordHeader h = decode_header(rec.data());
  change(h);
  const auto bytes = encode_header(h);
  std::memcpy(rec.data(), bytes.data(), bytes.size());
  return rec;
}

struct Corruption {
  const char* name;
  DropReason reason;
  bool sequence_known;
  std::function<std::vector<std::uint8_t>(std::vector<std::uint8_t>)> corrupt;
};

class Corrupted : public ::testing::TestWithParam<Corruption> {};

TEST_P(Corrupted, IsReportedAndTheNextRecordIsRead) {
  const Corruption& c = GetParam();
  const RawVolume bad = make_volume(5);
  const RawVolume good = make_volume(6);
  std::vector<std::uint8_t> stream = c.corrupt(record(bad));
  append(stream, record(good));
  for (std::size_t chunk : {std::size_t{1}, std::size_t{1000}, stream.size()}) {
    const auto events = parse_all(stream, chunk);
    ASSERT_EQ(events.size(), 2u) << c.name << " chunk " << chunk;
    ASSERT_TRUE(std::holds_alternative<DroppedRecord>(events[0])) << c.name;
    const auto& d = std::get<DroppedRecord>(events[0]);
    EXPECT_EQ(d.reason, c.reason) << c.name << ": " << to_string(d.reason) << " " << d.detail;
    EXPECT_FALSE(d.detail.empty());
    if (c.sequence_known) {
      ASSERT_TRUE(d.sequence.has_value()) << c.name;
      EXPECT_EQ(*d.sequence, 5u);
    } else {
      EXPECT_FALSE(d.sequence.has_value()) << c.name;
    }
    ASSERT_TRUE(std::holds_alternative<RawVolume>(events[1])) << c.name;
    expect_same(std::get<RawVolume>(events[1]), good);
  }
}

INSTANTIATE_TEST_SUITE_P(
    Classes, Corrupted,
    ::testing::Values(
        Corruption{"bad magic", DropReason::Garbage, false,
                   [](auto r) {
                     r[1] ^= 0xff;
                     return r;
                   }},
        Corruption{"header crc", DropReason::HeaderCrc, false,
                   [](auto r) {
                     r[17] ^= 0x10;
                     return r;
                   }},
        Corruption{"payload crc", DropReason::PayloadCrc, true,
                   [](auto r) {
                     r[64 + 1000] ^= 0x01;
                     return r;
                   }},
        Corruption{"payload crc field", DropReason::PayloadCrc, true,
                   [](auto r) {
                     r.back() ^= 0x80;
                     return r;
                   }},
        Corruption{"truncated", DropReason::Truncated, true,
                   [](auto r) {
                     r.resize(r.size() / 2);
                     return r;
                   }},
        Corruption{
            "oversize dims", DropReason::OversizeDims, true,
            [](auto r) { return with_header(r, [](RecordHeader& h) { h.dims[1] = 2000; }); }},
        Corruption{"zero dims", DropReason::ZeroDims, true,
                   [](auto r) { return with_header(r, [](RecordHeader& h) { h.dims[2] = 0; }); }},
        Corruption{
            "payload size", DropReason::PayloadSizeMismatch, true,
            [](auto r) { return with_header(r, [](RecordHeader& h) { h.payload_bytes -= 1; }); }},
        Corruption{"bad version", DropReason::BadVersion, true,
                   [](auto r) { return with_header(r, [](RecordHeader& h) { h.version = 2; }); }},
        Corruption{"bad kind", DropReason::BadKind, true,
                   [](auto r) { return with_header(r, [](RecordHeader& h) { h.kind = 9; }); }},
        Corruption{
            "bad voxel type", DropReason::BadVoxelType, true,
            [](auto r) { return with_header(r, [](RecordHeader& h) { h.voxel_type = 3; }); }},
        Corruption{"bad flags", DropReason::BadFlags, true,
                   [](auto r) { return with_header(r, [](RecordHeader& h) { h.flags = 1; }); }}),
    [](const auto& info) {
      std::string name = info.param.name;
      for (auto& ch : name) ch = std::isalnum(static_cast<unsigned char>(ch)) ? ch : '_';
      return name;
    });

TEST(Protocol, TruncatedAtEndOfInputIsReportedByFinish) {
  auto rec = record(make_volume(9));
  rec.resize(rec.size() - 10);
  const auto events = parse_all(rec, 512);
  ASSERT_EQ(events.size(), 1u);
  const auto& d = std::get<DroppedRecord>(events[0]);
  EXPECT_EQ(d.reason, DropReason::Truncated);
  EXPECT_EQ(d.sequence, std::optional<std::uint64_t>(9));
  // Cut inside the header: still truncated, sequence unknown.
  const auto head = std::vector<std::uint8_t>(rec.begin(), rec.begin() + 30);
  const auto events2 = parse_all(head, 512);
  ASSERT_EQ(events2.size(), 1u);
  EXPECT_EQ(std::get<DroppedRecord>(events2[0]).reason, DropReason::Truncated);
  EXPECT_FALSE(std::get<DroppedRecord>(events2[0]).sequence);
}

TEST(Protocol, ResynchronisesAfterRandomGarbage) {
  std::mt19937 rng(42);
  std::vector<std::uint8_t> stream;
  const int n = 30;
  int garbage_runs = 0;
  for (int s = 0; s < n; ++s) {
    if (rng() % 2 == 0) {
      std::vector<std::uint8_t> junk(1 + rng() % 300);
      for (auto& b : junk) b = static_cast<std::uint8_t>(rng());
      if (rng() % 3 == 0) std::memcpy(junk.data(), "USV1", std::min<std::size_t>(4, junk.size()));
      append(stream, junk);
      ++garbage_runs;
    }
    append(stream, record(make_volume(s, {16, 8, 8})));
  }
  const auto events = parse_all(stream, 333);
  std::vector<std::uint64_t> got;
  int drops = 0;
  for (const auto& e : events) {
    if (const auto* v = std::get_if<RawVolume>(&e)) got.push_back(v->sequence);
    if (const auto* d = std::get_if<DroppedRecord>(&e)) {
      ++drops;
      EXPECT_TRUE(d->reason == DropReason::Garbage || d->reason == DropReason::HeaderCrc ||
                  d->reason == DropReason::Truncated)
          << to_string(d->reason);
    }
  }
  ASSERT_EQ(got.size(), static_cast<std::size_t>(n)) << "no good record may be lost";
  for (int s = 0; s < n; ++s) EXPECT_EQ(got[s], static_cast<std::uint64_t>(s));
  EXPECT_EQ(drops, garbage_runs) << "each garbage run is reported exactly once";
}

TEST(Protocol, HugeDimsAreRefusedWithoutAllocating) {
  RecordHeader h;
  h.sequence = 3;
  h.dims = {65535, 65535, 65535};
  h.voxel_type = 2;
  h.payload_bytes = 0xffffffffu;
  const auto header = encode_header(h);
  for (const ParserLimits limits :
       {ParserLimits{}, ParserLimits{{65535, 65535, 65535}, 1ull << 30}}) {
    StreamParser parser(limits);
    g_largest = 0;
    g_track = true;
    parser.feed(header.data(), header.size());
    auto event = parser.next_event();
    g_track = false;
    ASSERT_TRUE(event.has_value());
    const auto& d = std::get<DroppedRecord>(*event);
    EXPECT_EQ(d.reason, DropReason::OversizeDims) << d.detail;
    EXPECT_EQ(d.sequence, std::optional<std::uint64_t>(3));
    EXPECT_LT(g_largest.load(), 64u * 1024u) << "the parser allocated from an unverified size";
  }
}

TEST(Protocol, SequenceTrackerFindsGapsAndRestarts) {
  SequenceTracker t;
  EXPECT_FALSE(t.observe_volume(10));
  EXPECT_FALSE(t.observe_volume(11));
  auto gap = t.observe_volume(15);
  ASSERT_TRUE(gap);
  EXPECT_EQ(gap->first_missing, 12u);
  EXPECT_EQ(gap->count, 3u);
  EXPECT_FALSE(t.observe_next(16));  // heartbeat: nothing missing
  gap = t.observe_next(18);          // heartbeat announces 18: 16 and 17 were lost
  ASSERT_TRUE(gap);
  EXPECT_EQ(gap->first_missing, 16u);
  EXPECT_EQ(gap->count, 2u);
  EXPECT_FALSE(t.observe_volume(0)) << "a probe restart is not a gap";
  EXPECT_FALSE(t.observe_volume(1));
}

TEST(Protocol, DecoderReportsLostBeforeTheVolumeAndAccountsBadRecords) {
  SourceOptions options;
  internal::StreamDecoder decoder(options);
  std::vector<std::uint8_t> stream;
  append(stream, record(make_volume(0)));
  append(stream, record(make_volume(1)));
  append(stream, record(make_volume(4)));  // 2, 3 lost
  auto bad = record(make_volume(5));
  bad[200] ^= 1;  // payload crc: sequence 5 is accounted as a bad record, not lost
  append(stream, bad);
  append(stream, record(make_volume(6)));
  append(stream, encode_end_of_stream(9, 0));  // 7, 8 lost just before the end
  decoder.feed(stream.data(), stream.size());
  std::vector<internal::NextResult> results;
  while (auto r = decoder.next()) results.push_back(std::move(*r));
  ASSERT_EQ(results.size(), 8u);
  EXPECT_EQ(results[0]->sequence, 0u);
  EXPECT_EQ(results[1]->sequence, 1u);
  ASSERT_FALSE(results[2]);
  EXPECT_EQ(results[2].error().code, AcquireError::Code::Lost);
  EXPECT_EQ(results[2].error().sequence, std::optional<std::uint64_t>(2));
  EXPECT_EQ(results[2].error().count, 2u);
  EXPECT_EQ(results[3]->sequence, 4u);
  ASSERT_FALSE(results[4]);
  EXPECT_EQ(results[4].error().code, AcquireError::Code::BadRecord);
  EXPECT_EQ(results[4].error().sequence, std::optional<std::uint64_t>(5));
  EXPECT_EQ(results[5]->sequence, 6u);
  ASSERT_FALSE(results[6]);
  EXPECT_EQ(results[6].error().code, AcquireError::Code::Lost);
  EXPECT_EQ(results[6].error().count, 2u);
  ASSERT_FALSE(results[7]);
  EXPECT_EQ(results[7].error().code, AcquireError::Code::EndOfStream);
  EXPECT_TRUE(decoder.end_of_stream_seen());
}

}  // namespace
}  // namespace sonomesh::acquire
