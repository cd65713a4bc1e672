// Probe stream protocol v1 (docs/protocol.md): encoding, incremental parsing, gap tracking.
#include "acquire/protocol.h"

#include <zlib.h>

#include <bit>
#include <chrono>
#include <cstring>
#include <limits>
#include <string>

namespace sonomesh::acquire {
namespace {

// Explicit little-endian field access: the wire format must not depend on the host.
void put_u16(std::uint8_t* p, std::uint16_t v) {
  p[0] = static_cast<std::uint8_t>(v);
  p[1] = static_cast<std::uint8_t>(v >> 8);
}
void put_u32(std::uint8_t* p, std::uint32_t v) {
  for (int i = 0; i < 4; ++i) p[i] = static_cast<std::uint8_t>(v >> (8 * i));
}
void put_u64(std::uint8_t* p, std::uint64_t v) {
  for (int i = 0; i < 8; ++i) p[i] = static_cast<std::uint8_t>(v >> (8 * i));
}
void put_f32(std::uint8_t* p, float v) { put_u32(p, std::bit_cast<std::uint32_t>(v)); }
std::uint16_t get_u16(const std::uint8_t* p) {
  return static_cast<std::uint16_t>(p[0] | (p[1] << 8));
}
std::uint32_t get_u32(const std::uint8_t* p) {
  std::uint32_t v = 0;
  for (int i = 3; i >= 0; --i) v = (v << 8) | p[i];
  return v;
}
std::uint64_t get_u64(const std::uint8_t* p) {
  std::uint64_t v = 0;
  for (int i = 7; i >= 0; --i) v = (v << 8) | p[i];
  return v;
}
float get_f32(const std::uint8_t* p) { return std::bit_cast<float>(get_u32(p)); }

std::vector<std::uint8_t> encode_marker(RecordKind kind, std::uint64_t next_sequence,
                                        std::uint64_t timestamp_ns) {
  RecordHeader header;
  header.kind = static_cast<std::uint16_t>(kind);
  header.sequence = next_sequence;
  header.timestamp_ns = timestamp_ns;
  header.voxel_type = 0;
  header.spacing_mm = {0.0f, 0.0f, 0.0f};
  const auto bytes = encode_header(header);
  std::vector<std::uint8_t> out(bytes.begin(), bytes.end());
  out.resize(kHeaderBytes + kPayloadCrcBytes, 0);  // payload_crc32 of nothing = 0
  return out;
}

DroppedRecord drop(DropReason reason, std::optional<std::uint64_t> sequence, std::uint16_t kind,
                   std::uint64_t bytes, std::string detail) {
  return DroppedRecord{reason, sequence, kind, bytes, std::move(detail)};
}

}  // namespace

std::uint32_t crc32(const std::uint8_t* data, std::size_t size) {
  uLong crc = ::crc32(0L, Z_NULL, 0);
  // zlib takes uInt lengths; feed large buffers in pieces.
  while (size > 0) {
    const uInt chunk = static_cast<uInt>(std::min<std::size_t>(size, 1u << 30));
    crc = ::crc32(crc, data, chunk);
    data += chunk;
    size -= chunk;
  }
  return static_cast<std::uint32_t>(crc);
}

std::array<std::uint8_t, kHeaderBytes> encode_header(const RecordHeader& h) {
  std::array<std::uint8_t, kHeaderBytes> b{};
  std::memcpy(b.data(), kMagic.data(), 4);
  put_u16(&b[4], h.version);
  put_u16(&b[6], h.kind);
  put_u64(&b[8], h.sequence);
  put_u64(&b[16], h.timestamp_ns);
  for (int a = 0; a < 3; ++a) put_u16(&b[24 + 2 * a], h.dims[a]);
  b[30] = h.voxel_type;
  b[31] = h.flags;
  for (int a = 0; a < 3; ++a) put_f32(&b[32 + 4 * a], h.spacing_mm[a]);
  for (int a = 0; a < 3; ++a) put_f32(&b[44 + 4 * a], h.origin_mm[a]);
  put_u32(&b[56], h.payload_bytes);
  put_u32(&b[60], crc32(b.data(), 60));
  return b;
}

RecordHeader decode_header(const std::uint8_t* b) {
  RecordHeader h;
  h.version = get_u16(b + 4);
  h.kind = get_u16(b + 6);
  h.sequence = get_u64(b + 8);
  h.timestamp_ns = get_u64(b + 16);
  for (int a = 0; a < 3; ++a) h.dims[a] = get_u16(b + 24 + 2 * a);
  h.voxel_type = b[30];
  h.flags = b[31];
  for (int a = 0; a < 3; ++a) h.spacing_mm[a] = get_f32(b + 32 + 4 * a);
  for (int a = 0; a < 3; ++a) h.origin_mm[a] = get_f32(b + 44 + 4 * a);
  h.payload_bytes = get_u32(b + 56);
  h.header_crc32 = get_u32(b + 60);
  return h;
}

bool header_crc_ok(const std::uint8_t* bytes) {
  return std::memcmp(bytes, kMagic.data(), 4) == 0 && get_u32(bytes + 60) == crc32(bytes, 60);
}

tl::expected<std::vector<std::uint8_t>, AcquireError> encode_volume_record(const RawVolume& v) {
  auto invalid = [&](std::string what) {
    return tl::make_unexpected(AcquireError{AcquireError::Code::InvalidArgument, 0,
                                            "cannot encode volume: " + what, v.sequence, 0});
  };
  std::uint64_t voxels = 1;
  for (int a = 0; a < 3; ++a) {
    if (v.dims[a] <= 0 || v.dims[a] > 65535) {
      return invalid("dimension " + std::to_string(v.dims[a]) + " outside 1..65535");
    }
    voxels *= static_cast<std::uint64_t>(v.dims[a]);
  }
  if (v.type != ProbeVoxelType::UInt8 && v.type != ProbeVoxelType::UInt16) {
    return invalid("unknown voxel type");
  }
  const std::uint64_t payload = voxels * bytes_per_voxel(v.type);
  if (payload != v.voxels.size()) {
    return invalid("payload has " + std::to_string(v.voxels.size()) + " bytes, dims need " +
                   std::to_string(payload));
  }
  if (payload > std::numeric_limits<std::uint32_t>::max()) {
    return invalid("payload above 4 GiB");
  }
  RecordHeader h;
  h.kind = static_cast<std::uint16_t>(RecordKind::Volume);
  h.sequence = v.sequence;
  h.timestamp_ns = v.timestamp_ns;
  for (int a = 0; a < 3; ++a) h.dims[a] = static_cast<std::uint16_t>(v.dims[a]);
  h.voxel_type = static_cast<std::uint8_t>(v.type);
  h.spacing_mm = v.spacing_mm;
  h.origin_mm = v.origin_mm;
  h.payload_bytes = static_cast<std::uint32_t>(payload);
  std::vector<std::uint8_t> out(kHeaderBytes + payload + kPayloadCrcBytes);
  const auto header = encode_header(h);
  std::memcpy(out.data(), header.data(), kHeaderBytes);
  if (payload > 0) std::memcpy(out.data() + kHeaderBytes, v.voxels.data(), payload);
  put_u32(out.data() + kHeaderBytes + payload, crc32(v.voxels.data(), payload));
  return out;
}

std::vector<std::uint8_t> encode_heartbeat(std::uint64_t next_sequence,
                                           std::uint64_t timestamp_ns) {
  return encode_marker(RecordKind::Heartbeat, next_sequence, timestamp_ns);
}

std::vector<std::uint8_t> encode_end_of_stream(std::uint64_t next_sequence,
                                               std::uint64_t timestamp_ns) {
  return encode_marker(RecordKind::EndOfStream, next_sequence, timestamp_ns);
}

const char* to_string(DropReason reason) {
  switch (reason) {
    case DropReason::Garbage:
      return "garbage";
    case DropReason::HeaderCrc:
      return "header-crc";
    case DropReason::PayloadCrc:
      return "payload-crc";
    case DropReason::Truncated:
      return "truncated";
    case DropReason::OversizeDims:
      return "oversize-dims";
    case DropReason::ZeroDims:
      return "zero-dims";
    case DropReason::PayloadSizeMismatch:
      return "payload-size-mismatch";
    case DropReason::BadVersion:
      return "bad-version";
    case DropReason::BadKind:
      return "bad-kind";
    case DropReason::BadVoxelType:
      return "bad-voxel-type";
    case DropReason::BadFlags:
      return "bad-flags";
  }
  return "unknown";
}

// ---------------------------------------------------------------------------------------------
// StreamParser

namespace {

struct ScanResult {
  std::size_t pos;  // first good header, or first position that cannot be decided yet
  bool good;
};

// Finds the first magic in [from, size) whose 64-byte header has a good CRC. Candidates whose
// header is not complete yet stop the scan undecided, so no possible record start is skipped.
ScanResult scan_for_header(const std::uint8_t* buf, std::size_t from, std::size_t size) {
  std::size_t q = from;
  while (q < size) {
    const void* hit = std::memchr(buf + q, kMagic[0], size - q);
    if (hit == nullptr) return {size, false};
    q = static_cast<std::size_t>(static_cast<const std::uint8_t*>(hit) - buf);
    const std::size_t rem = size - q;
    if (rem < 4) {
      if (std::memcmp(buf + q, kMagic.data(), rem) == 0) return {q, false};
      ++q;
      continue;
    }
    if (std::memcmp(buf + q, kMagic.data(), 4) != 0) {
      ++q;
      continue;
    }
    if (rem < kHeaderBytes) return {q, false};
    if (header_crc_ok(buf + q)) return {q, true};
    ++q;
  }
  return {size, false};
}

struct Refusal {
  DropReason reason;
  std::string detail;
};

// The header checks a record must pass before its payload is awaited (dims and payload size are
// refused here, so nothing is allocated for them).
std::optional<Refusal> check_header(const RecordHeader& h, const ParserLimits& limits) {
  if (h.version != kProtocolVersion) {
    return Refusal{DropReason::BadVersion, "version " + std::to_string(h.version) + " (want 1)"};
  }
  if (h.kind < 1 || h.kind > 3) {
    return Refusal{DropReason::BadKind, "kind " + std::to_string(h.kind)};
  }
  if (h.flags != 0) {
    return Refusal{DropReason::BadFlags, "flags " + std::to_string(h.flags) + " (reserved, 0)"};
  }
  if (static_cast<RecordKind>(h.kind) == RecordKind::Volume) {
    if (h.voxel_type != 1 && h.voxel_type != 2) {
      return Refusal{DropReason::BadVoxelType, "voxel type " + std::to_string(h.voxel_type)};
    }
    const std::string dims_text = std::to_string(h.dims[0]) + "x" + std::to_string(h.dims[1]) +
                                  "x" + std::to_string(h.dims[2]);
    if (h.dims[0] == 0 || h.dims[1] == 0 || h.dims[2] == 0) {
      return Refusal{DropReason::ZeroDims, "dims " + dims_text};
    }
    for (int a = 0; a < 3; ++a) {
      if (h.dims[a] > limits.max_dims[a]) {
        return Refusal{DropReason::OversizeDims, "dims " + dims_text + " above the limit " +
                                                     std::to_string(limits.max_dims[0]) + "x" +
                                                     std::to_string(limits.max_dims[1]) + "x" +
                                                     std::to_string(limits.max_dims[2])};
      }
    }
    const std::uint64_t want =
        std::uint64_t{h.dims[0]} * h.dims[1] * h.dims[2] * static_cast<std::uint64_t>(h.voxel_type);
    if (want > limits.max_payload_bytes) {
      return Refusal{DropReason::OversizeDims, "payload of " + std::to_string(want) +
                                                   " bytes above the limit " +
                                                   std::to_string(limits.max_payload_bytes)};
    }
    if (h.payload_bytes != want) {
      return Refusal{DropReason::PayloadSizeMismatch,
                     "payload_bytes " + std::to_string(h.payload_bytes) + ", dims " + dims_text +
                         " need " + std::to_string(want)};
    }
  } else if (h.payload_bytes != 0) {
    return Refusal{DropReason::PayloadSizeMismatch,
                   "payload_bytes " + std::to_string(h.payload_bytes) +
                       " in a heartbeat / end-of-stream record (must be 0)"};
  }
  return std::nullopt;
}

ParserEvent make_event(const RecordHeader& h, RecordKind kind, const std::uint8_t* payload) {
  switch (kind) {
    case RecordKind::Volume: {
      RawVolume v;
      v.sequence = h.sequence;
      v.timestamp_ns = h.timestamp_ns;
      v.dims = {h.dims[0], h.dims[1], h.dims[2]};
      v.type = static_cast<ProbeVoxelType>(h.voxel_type);
      v.spacing_mm = h.spacing_mm;
      v.origin_mm = h.origin_mm;
      v.voxels.assign(payload, payload + h.payload_bytes);
      v.received = std::chrono::steady_clock::now();
      return v;
    }
    case RecordKind::Heartbeat:
      return Heartbeat{h.sequence, h.timestamp_ns};
    case RecordKind::EndOfStream:
      break;
  }
  return EndOfStream{h.sequence, h.timestamp_ns};
}

}  // namespace

StreamParser::StreamParser(ParserLimits limits) : limits_(limits) {}

void StreamParser::feed(const std::uint8_t* data, std::size_t size) {
  // Compact once the consumed prefix dominates, so the buffer holds about one record at most.
  if (pos_ > 0 && pos_ >= buffer_.size() / 2) {
    buffer_.erase(buffer_.begin(), buffer_.begin() + static_cast<std::ptrdiff_t>(pos_));
    scanned_to_ = scanned_to_ > pos_ ? scanned_to_ - pos_ : 0;
    pos_ = 0;
  }
  buffer_.insert(buffer_.end(), data, data + size);
}

void StreamParser::consume(std::size_t n) {
  pos_ += n;
  scanned_to_ = 0;
  if (pos_ == buffer_.size()) {
    buffer_.clear();
    pos_ = 0;
  }
}

std::optional<std::size_t> StreamParser::find_good_header(std::size_t from, std::size_t to) const {
  const ScanResult r = scan_for_header(buffer_.data(), from, to);
  if (r.good) return r.pos;
  return std::nullopt;
}

std::optional<ParserEvent> StreamParser::next_event() {
  if (!ready_.empty()) {
    ParserEvent event = std::move(ready_.front());
    ready_.pop_front();
    return event;
  }
  return parse_one();
}

std::optional<ParserEvent> StreamParser::parse_one() {
  for (;;) {
    const std::size_t avail = buffer_.size() - pos_;
    if (silent_skip_ || pending_garbage_) {
      const ScanResult r = scan_for_header(buffer_.data(), pos_, buffer_.size());
      const std::size_t n = r.pos - pos_;
      if (pending_garbage_) pending_garbage_->bytes_skipped += n;
      consume(n);
      if (!r.good) return std::nullopt;
      silent_skip_ = false;
      if (pending_garbage_) {
        DroppedRecord event = std::move(*pending_garbage_);
        pending_garbage_.reset();
        return event;
      }
      continue;
    }
    if (avail < 4) return std::nullopt;
    const std::uint8_t* p = buffer_.data() + pos_;
    if (std::memcmp(p, kMagic.data(), 4) != 0) {
      pending_garbage_ =
          drop(DropReason::Garbage, std::nullopt, 0, 0, "bytes without a record magic skipped");
      continue;
    }
    if (avail < kHeaderBytes) return std::nullopt;
    if (!header_crc_ok(p)) {
      consume(1);
      silent_skip_ = true;
      return drop(DropReason::HeaderCrc, std::nullopt, 0, 1,
                  "header crc32 mismatch; resynchronising on the next magic");
    }
    const RecordHeader h = decode_header(p);
    const std::optional<std::uint64_t> seq = h.sequence;
    if (auto refusal = check_header(h, limits_)) {
      consume(kHeaderBytes);
      silent_skip_ = true;
      return drop(refusal->reason, seq, h.kind, kHeaderBytes, std::move(refusal->detail));
    }
    const auto kind = static_cast<RecordKind>(h.kind);
    const std::size_t total = kHeaderBytes + h.payload_bytes + kPayloadCrcBytes;
    // A record cut short is followed directly by the next record; look for a good header inside
    // the part received so far, so a truncation is detected without waiting for `total` bytes.
    const std::size_t scan_end = pos_ + std::min(avail, total);
    const std::size_t scan_from = std::max(scanned_to_, pos_ + kHeaderBytes);
    if (scan_from < scan_end) {
      const ScanResult r = scan_for_header(buffer_.data(), scan_from, scan_end);
      if (r.good) {
        const std::size_t got = r.pos - pos_;
        consume(got);
        return drop(DropReason::Truncated, seq, h.kind, got,
                    "record cut short after " + std::to_string(got) + " of " +
                        std::to_string(total) + " bytes: the next record starts inside it");
      }
      scanned_to_ = r.pos;
    }
    if (avail < total) return std::nullopt;

    const std::uint8_t* payload = p + kHeaderBytes;
    const std::uint32_t want_crc = get_u32(payload + h.payload_bytes);
    const std::uint32_t got_crc = crc32(payload, h.payload_bytes);
    if (want_crc != got_crc) {
      consume(total);
      return drop(DropReason::PayloadCrc, seq, h.kind, total, "payload crc32 mismatch");
    }
    ParserEvent event = make_event(h, kind, payload);
    consume(total);
    return event;
  }
}

void StreamParser::finish() {
  while (auto event = parse_one()) ready_.push_back(std::move(*event));
  const std::size_t avail = buffer_.size() - pos_;
  const std::uint8_t* p = buffer_.data() + pos_;
  if (pending_garbage_) {
    pending_garbage_->bytes_skipped += avail;
    ready_.push_back(std::move(*pending_garbage_));
  } else if (!silent_skip_ && avail > 0) {
    const bool magic_prefix = std::memcmp(p, kMagic.data(), std::min<std::size_t>(avail, 4)) == 0;
    if (avail >= kHeaderBytes && header_crc_ok(p)) {
      const RecordHeader h = decode_header(p);
      ready_.push_back(drop(DropReason::Truncated, h.sequence, h.kind, avail,
                            "input ended after " + std::to_string(avail) + " of " +
                                std::to_string(kHeaderBytes + h.payload_bytes + kPayloadCrcBytes) +
                                " bytes of the record"));
    } else if (magic_prefix) {
      ready_.push_back(
          drop(DropReason::Truncated, std::nullopt, 0, avail,
               "input ended inside a record header (" + std::to_string(avail) + " bytes)"));
    } else {
      ready_.push_back(drop(DropReason::Garbage, std::nullopt, 0, avail,
                            "bytes without a record magic at the end of input"));
    }
  }
  reset();
}

void StreamParser::reset() {
  buffer_.clear();
  pos_ = 0;
  scanned_to_ = 0;
  pending_garbage_.reset();
  silent_skip_ = false;
}

}  // namespace sonomesh::acquire
