#pragma once
/// @file
/// @brief Probe stream protocol v1: record encoding, the incremental parser, gap tracking.
///
/// The full text is docs/protocol.md. A stream is a sequence of records, little endian: a
/// 64-byte header (magic "USV1", version, kind, sequence, timestamp, dims, voxel type, spacing,
/// origin, payload size, header CRC32), then for volumes the payload and its CRC32. Sockets, USB
/// bulk IN and .usv recording files all carry the same bytes.

#include <array>
#include <cstddef>
#include <cstdint>
#include <deque>
#include <optional>
#include <string>
#include <tl/expected.hpp>
#include <variant>
#include <vector>

#include "acquire/acquire.h"
#include "acquire/raw_volume.h"

namespace sonomesh::acquire {

inline constexpr std::size_t kHeaderBytes = 64;
inline constexpr std::size_t kPayloadCrcBytes = 4;
inline constexpr std::array<std::uint8_t, 4> kMagic{'U', 'S', 'V', '1'};
inline constexpr std::uint16_t kProtocolVersion = 1;

enum class RecordKind : std::uint16_t { Volume = 1, Heartbeat = 2, EndOfStream = 3 };

/// zlib crc32 of a byte range.
std::uint32_t crc32(const std::uint8_t* data, std::size_t size);

/// The header fields as they are on the wire (no validation implied).
struct RecordHeader {
  std::uint16_t version = kProtocolVersion;
  std::uint16_t kind = static_cast<std::uint16_t>(RecordKind::Volume);
  std::uint64_t sequence = 0;
  std::uint64_t timestamp_ns = 0;
  std::array<std::uint16_t, 3> dims{};
  std::uint8_t voxel_type = 1;
  std::uint8_t flags = 0;
  std::array<float, 3> spacing_mm{1.0f, 1.0f, 1.0f};
  std::array<float, 3> origin_mm{0.0f, 0.0f, 0.0f};
  std::uint32_t payload_bytes = 0;
  std::uint32_t header_crc32 = 0;  // encode_header computes it; decode_header reads it
};

/// 64 header bytes with the header CRC computed over bytes 0..59 (header.header_crc32 ignored).
std::array<std::uint8_t, kHeaderBytes> encode_header(const RecordHeader& header);
/// Reads the fields of 64 header bytes as they are (call header_crc_ok to trust them).
RecordHeader decode_header(const std::uint8_t* bytes);
/// True if bytes 0..3 are the magic and bytes 60..63 hold the crc32 of bytes 0..59.
bool header_crc_ok(const std::uint8_t* bytes);

/// One volume record: header, payload, payload CRC. InvalidArgument if the dims do not fit u16,
/// are zero, or the voxel count does not match dims and type.
tl::expected<std::vector<std::uint8_t>, AcquireError> encode_volume_record(const RawVolume& volume);
/// Heartbeat / end-of-stream records (64-byte header + zero payload CRC). `next_sequence` is the
/// sequence the next volume would carry (last volume + 1; 0 before any), so a reader can detect
/// volumes lost just before an idle period or the end.
std::vector<std::uint8_t> encode_heartbeat(std::uint64_t next_sequence, std::uint64_t timestamp_ns);
std::vector<std::uint8_t> encode_end_of_stream(std::uint64_t next_sequence,
                                               std::uint64_t timestamp_ns);

struct Heartbeat {
  std::uint64_t next_sequence = 0;
  std::uint64_t timestamp_ns = 0;
};
struct EndOfStream {
  std::uint64_t next_sequence = 0;
  std::uint64_t timestamp_ns = 0;
};

enum class DropReason {
  Garbage,       // bytes that do not start a record (bad magic); skipped up to the next magic
  HeaderCrc,     // header CRC mismatch: nothing in the header is trusted
  PayloadCrc,    // payload CRC mismatch
  Truncated,     // record cut short (end of input, or the next record starts inside it)
  OversizeDims,  // dims or payload above the configured limits
  ZeroDims,      // a volume with a zero dimension
  PayloadSizeMismatch,  // payload_bytes != nx*ny*nz*bytes per voxel (or != 0 for heartbeat/EOS)
  BadVersion,           // version != 1
  BadKind,              // kind not 1..3
  BadVoxelType,         // voxel type not 1 or 2
  BadFlags              // flags != 0 (reserved in v1)
};
const char* to_string(DropReason reason);

struct DroppedRecord {
  DropReason reason = DropReason::Garbage;
  std::optional<std::uint64_t> sequence;  // set when the header CRC was good
  std::uint16_t kind = 0;                 // the header's kind when its CRC was good, else 0
  std::uint64_t bytes_skipped = 0;        // bytes discarded for this event (so far)
  std::string detail;                     // one line
};

using ParserEvent = std::variant<RawVolume, Heartbeat, EndOfStream, DroppedRecord>;

struct ParserLimits {
  std::array<int, 3> max_dims{1024, 1024, 1024};
  std::uint64_t max_payload_bytes = 1ull << 30;
};

/// Incremental push parser. feed() bytes as they arrive, then drain next_event() until it returns
/// nullopt (more bytes needed). Never allocates from an unverified header: the header CRC is
/// checked first and limits before anything is sized from it; buffered bytes are only ever those
/// fed. After a corrupt record it resynchronises on the next magic with a good header CRC; each
/// corrupt record is reported once, the bytes skipped with it are not reported again.
class StreamParser {
 public:
  explicit StreamParser(ParserLimits limits = {});
  void feed(const std::uint8_t* data, std::size_t size);
  std::optional<ParserEvent> next_event();
  /// End of input: a partial record still buffered is reported as Truncated (or Garbage) by the
  /// following next_event() calls; afterwards the parser is empty, ready for a new stream.
  void finish();
  /// Forgets buffered bytes without reporting them.
  void reset();
  std::size_t buffered_bytes() const { return buffer_.size() - pos_; }

 private:
  std::optional<ParserEvent> parse_one();
  std::optional<std::size_t> find_good_header(std::size_t from, std::size_t to) const;
  void consume(std::size_t n);

  ParserLimits limits_;
  std::vector<std::uint8_t> buffer_;
  std::size_t pos_ = 0;
  std::optional<DroppedRecord> pending_garbage_;  // garbage run not yet ended by a good header
  bool silent_skip_ = false;                      // skipping the rest of an already reported record
  std::size_t scanned_to_ = 0;  // lookahead inside a waiting record's payload (absolute offset)
  std::deque<ParserEvent> ready_;
};

/// Sequence-gap tracking used by every source. Volumes carry +1 sequences; heartbeat / end of
/// stream carry the next sequence. A sequence that goes backwards means the probe restarted:
/// tracking starts again from it (no gap).
class SequenceTracker {
 public:
  struct Gap {
    std::uint64_t first_missing = 0;
    std::uint64_t count = 0;
  };
  /// A volume (or a dropped volume record with an intact header) with this sequence.
  std::optional<Gap> observe_volume(std::uint64_t sequence);
  /// A heartbeat / end of stream announcing the next sequence.
  std::optional<Gap> observe_next(std::uint64_t next_sequence);
  void reset() { expected_.reset(); }
  std::optional<std::uint64_t> expected() const { return expected_; }

 private:
  std::optional<std::uint64_t> expected_;
};

}  // namespace sonomesh::acquire
