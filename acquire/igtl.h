#pragma once
/// @file
/// @brief OpenIGTLink framing and IMAGE bodies, read by hand (header versions 1 and 2).
///
/// Every message: a 58-byte big-endian header (version u16, type char[12], device name char[20],
/// timestamp u64 = seconds u32 + fraction u32 / 2^32, body size u64, CRC-64 of the body u64:
/// ECMA-182 polynomial, MSB first, initial value 0, as OpenIGTLink computes it), then the body.
/// Version 2 bodies are: extended header (ext size u16, metadata header size u16, metadata size
/// u32, MESSAGE_ID u32), content, metadata header, metadata. docs/protocol.md has the details.

#include <array>
#include <cstddef>
#include <cstdint>
#include <optional>
#include <string>
#include <tl/expected.hpp>
#include <variant>
#include <vector>

#include "acquire/raw_volume.h"

namespace sonomesh::acquire::igtl {

constexpr std::size_t kHeaderBytes = 58;
constexpr std::size_t kExtendedHeaderBytes = 12;
constexpr std::size_t kImageHeaderBytes = 72;

struct Header {
  std::uint16_t version = 0;
  std::string type;    // "IMAGE", "TRANSFORM", ... (NUL padding removed)
  std::string device;  // device name (NUL padding removed)
  std::uint64_t timestamp = 0;
  std::uint64_t body_bytes = 0;
  std::uint64_t crc = 0;
};

/// CRC-64 (ECMA-182) continuing from `crc` (0 to start), as OpenIGTLink's crc64().
std::uint64_t crc64(const std::uint8_t* data, std::size_t size, std::uint64_t crc = 0);

/// Parses the first kHeaderBytes of `data`. An error (the stream cannot be framed any more) if
/// the version is not 1..3 or the type is not printable ASCII.
tl::expected<Header, std::string> parse_header(const std::uint8_t* data);

/// Nanoseconds of an OpenIGTLink timestamp (seconds << 32 | fraction).
std::uint64_t timestamp_ns(std::uint64_t igtl_timestamp);

/// The message content of a whole body: for version 1 the body, for version >= 2 the part
/// between the extended header and the metadata, with the MESSAGE_ID.
struct Content {
  const std::uint8_t* data = nullptr;
  std::size_t size = 0;
  std::optional<std::uint32_t> message_id;
};
tl::expected<Content, std::string> message_content(const Header& header,
                                                   const std::vector<std::uint8_t>& body);

/// Limits an IMAGE must respect (checked before any voxel is copied).
struct ImageLimits {
  std::array<int, 3> max_dims{1024, 1024, 1024};
  std::uint64_t max_payload_bytes = 1ull << 30;
};

/// An IMAGE content as a RawVolume: 1 component, uint8 or uint16, either endianness, RAS or
/// LPS; the subvolume must be the whole image. Geometry: spacing = column norms of the matrix,
/// direction = the normalised columns in LPS, origin = the corner voxel's centre in LPS (the
/// matrix's p is the image centre: corner = p - sum_c dir_c * spacing_c * (size_c - 1) / 2,
/// OpenIGTLink's and 3D Slicer's convention). An error names the reason ("scalar type int16 ...").
tl::expected<RawVolume, std::string> decode_image(const std::uint8_t* content, std::size_t size,
                                                  const ImageLimits& limits);

/// Splits a byte stream into messages. Bodies above `max_body_bytes` are skipped without being
/// stored (an Oversize event at their header).
class MessageReader {
 public:
  struct Message {
    Header header;
    std::vector<std::uint8_t> body;
    bool crc_ok = false;
  };
  struct Oversize {
    Header header;
  };
  struct FramingLost {
    std::string why;  // the stream cannot be read on: reconnect
  };
  struct Truncated {
    Header header;
    std::uint64_t got_bytes = 0;  // of header.body_bytes
    bool oversize = false;        // its Oversize event came already
  };
  using Event = std::variant<Message, Oversize, FramingLost, Truncated>;

  explicit MessageReader(std::uint64_t max_body_bytes) : max_body_bytes_(max_body_bytes) {}
  void feed(const std::uint8_t* data, std::size_t size);
  /// The next event, or nullopt when more bytes are needed. After FramingLost only reset() helps.
  std::optional<Event> next();
  /// The input ended: a message in progress becomes Truncated; the reader starts empty.
  std::optional<Event> end_of_input();
  void reset();

 private:
  std::uint64_t max_body_bytes_;
  std::vector<std::uint8_t> pending_;  // bytes not consumed yet
  std::size_t consumed_ = 0;           // of pending_
  std::optional<Header> header_;       // the message whose body is awaited
  bool skipping_ = false;              // the awaited body is discarded, not stored
  std::uint64_t skipped_bytes_ = 0;
  bool lost_ = false;
};

}  // namespace sonomesh::acquire::igtl
