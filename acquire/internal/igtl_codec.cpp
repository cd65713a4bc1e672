// OpenIGTLink by hand: header, CRC-64, version-2 body layout, IMAGE content, stream framing.
#include <algorithm>
#include <cmath>
#include <cstring>

#include "acquire/igtl.h"

namespace sonomesh::acquire::igtl {
namespace {

constexpr std::uint64_t kCrcPolynomial = 0x42F0E1EBA9EA3693ull;  // ECMA-182
constexpr std::size_t kCompactBytes = 1 << 20;

// Slicing by eight: t[k][b] is the CRC of byte b followed by k zero bytes, so eight bytes are
// folded in per step; one byte per step made the CRC most of an IMAGE's receive time.
struct CrcTables {
  std::array<std::array<std::uint64_t, 256>, 8> t{};
  CrcTables() {
    for (std::uint64_t i = 0; i < 256; ++i) {
      std::uint64_t crc = i << 56;
      for (int bit = 0; bit < 8; ++bit) {
        crc = (crc & (1ull << 63)) ? (crc << 1) ^ kCrcPolynomial : crc << 1;
      }
      t[0][i] = crc;
    }
    for (int k = 1; k < 8; ++k) {
      for (int i = 0; i < 256; ++i) t[k][i] = (t[k - 1][i] << 8) ^ t[0][t[k - 1][i] >> 56];
    }
  }
};

std::uint16_t be16(const std::uint8_t* p) { return static_cast<std::uint16_t>((p[0] << 8) | p[1]); }
std::uint32_t be32(const std::uint8_t* p) {
  return (std::uint32_t{p[0]} << 24) | (std::uint32_t{p[1]} << 16) | (std::uint32_t{p[2]} << 8) |
         std::uint32_t{p[3]};
}
std::uint64_t be64(const std::uint8_t* p) { return (std::uint64_t{be32(p)} << 32) | be32(p + 4); }
float be_float(const std::uint8_t* p) {
  const std::uint32_t bits = be32(p);
  float f;
  std::memcpy(&f, &bits, sizeof f);
  return f;
}

// A fixed-size, NUL-padded name field; true if every character before the padding prints.
bool read_name(const std::uint8_t* p, std::size_t size, std::string& out) {
  out.clear();
  for (std::size_t i = 0; i < size && p[i] != 0; ++i) {
    if (p[i] < 0x20 || p[i] > 0x7e) return false;
    out.push_back(static_cast<char>(p[i]));
  }
  return true;
}

const char* scalar_name(int code) {
  switch (code) {
    case 2:
      return "int8";
    case 3:
      return "uint8";
    case 4:
      return "int16";
    case 5:
      return "uint16";
    case 6:
      return "int32";
    case 7:
      return "uint32";
    case 10:
      return "float32";
    case 11:
      return "float64";
    default:
      return "unknown";
  }
}

using Vec = std::array<double, 3>;
double dot(const Vec& a, const Vec& b) { return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]; }

// The header fields of an IMAGE content that decide whether it can be used.
struct ImageHeader {
  int components = 0, scalar = 0, endian = 0, coordinate = 0;
  std::array<int, 3> size{}, sub_offset{}, sub_size{};
  std::array<Vec, 3> columns{};  // t, s, n: direction times spacing
  Vec centre{};
};

ImageHeader read_image_header(const std::uint8_t* c) {
  ImageHeader h;
  h.components = c[2];
  h.scalar = c[3];
  h.endian = c[4];
  h.coordinate = c[5];
  for (int a = 0; a < 3; ++a) {
    h.size[a] = be16(c + 6 + 2 * a);
    h.sub_offset[a] = be16(c + 60 + 2 * a);
    h.sub_size[a] = be16(c + 66 + 2 * a);
    for (int col = 0; col < 3; ++col) h.columns[col][a] = be_float(c + 12 + 4 * (3 * col + a));
    h.centre[a] = be_float(c + 48 + 4 * a);
  }
  return h;
}

// Type, layout and size checks: the first reason the content cannot be used, if any.
std::optional<std::string> check_image(const ImageHeader& h, std::size_t content_bytes,
                                       const ImageLimits& limits) {
  if (h.components != 1) return std::to_string(h.components) + " components (1 supported)";
  if (h.scalar != 3 && h.scalar != 5) {
    return std::string("scalar type ") + scalar_name(h.scalar) + " (" + std::to_string(h.scalar) +
           ") not supported (uint8, uint16)";
  }
  if (h.endian != 1 && h.endian != 2) return "endian code " + std::to_string(h.endian);
  if (h.coordinate != 1 && h.coordinate != 2) {
    return "coordinate code " + std::to_string(h.coordinate) + " (1 RAS, 2 LPS)";
  }
  std::uint64_t voxels = 1;
  for (int a = 0; a < 3; ++a) {
    if (h.size[a] < 1 || h.size[a] > limits.max_dims[a]) {
      return "size " + std::to_string(h.size[a]) + " on axis " + std::to_string(a) +
             " outside 1.." + std::to_string(limits.max_dims[a]);
    }
    if (h.sub_offset[a] != 0 || h.sub_size[a] != h.size[a]) {
      return "subvolume (offset " + std::to_string(h.sub_offset[a]) + ", size " +
             std::to_string(h.sub_size[a]) + " on axis " + std::to_string(a) +
             ") is not the whole image";
    }
    voxels *= static_cast<std::uint64_t>(h.size[a]);
  }
  const std::uint64_t bytes = voxels * (h.scalar == 5 ? 2 : 1);
  if (bytes > limits.max_payload_bytes) {
    return std::to_string(bytes) + " voxel bytes exceed the limit " +
           std::to_string(limits.max_payload_bytes);
  }
  if (content_bytes != kImageHeaderBytes + bytes) {
    return "image data is " + std::to_string(content_bytes - kImageHeaderBytes) +
           " bytes, its size and type need " + std::to_string(bytes);
  }
  return std::nullopt;
}

// Spacing, LPS direction and corner origin from the matrix: an error if it is not orthogonal.
std::optional<std::string> set_geometry(const ImageHeader& h, RawVolume& v) {
  std::array<Vec, 3> dir{};
  for (int c = 0; c < 3; ++c) {
    const double norm = std::sqrt(dot(h.columns[c], h.columns[c]));
    if (!std::isfinite(norm) || norm <= 1e-9) return "matrix column " + std::to_string(c) + " is 0";
    for (int a = 0; a < 3; ++a) dir[c][a] = h.columns[c][a] / norm;
    v.spacing_mm[c] = static_cast<float>(norm);
  }
  for (int c = 0; c < 3; ++c) {
    for (int d = c + 1; d < 3; ++d) {
      if (std::abs(dot(dir[c], dir[d])) > 1e-3) return "matrix columns are not orthogonal";
    }
  }
  Vec centre = h.centre;
  if (h.coordinate == 1) {  // RAS -> LPS: x and y change sign
    for (auto* p : {&centre, &dir[0], &dir[1], &dir[2]}) {
      (*p)[0] = -(*p)[0];
      (*p)[1] = -(*p)[1];
    }
  }
  for (int a = 0; a < 3; ++a) {
    double corner = centre[a];
    for (int c = 0; c < 3; ++c) corner -= dir[c][a] * v.spacing_mm[c] * (h.size[c] - 1) / 2.0;
    if (!std::isfinite(corner)) return "image position is not finite";
    v.origin_mm[a] = static_cast<float>(corner);
    for (int c = 0; c < 3; ++c) v.direction[3 * c + a] = static_cast<float>(dir[c][a]);
  }
  return std::nullopt;
}

}  // namespace

std::uint64_t crc64(const std::uint8_t* data, std::size_t size, std::uint64_t crc) {
  static const CrcTables tables;
  const auto& t = tables.t;
  std::size_t i = 0;
  for (; i + 8 <= size; i += 8) {
    crc ^= be64(data + i);
    crc = t[7][crc >> 56] ^ t[6][(crc >> 48) & 0xff] ^ t[5][(crc >> 40) & 0xff] ^
          t[4][(crc >> 32) & 0xff] ^ t[3][(crc >> 24) & 0xff] ^ t[2][(crc >> 16) & 0xff] ^
          t[1][(crc >> 8) & 0xff] ^ t[0][crc & 0xff];
  }
  for (; i < size; ++i) crc = t[0][((crc >> 56) ^ data[i]) & 0xff] ^ (crc << 8);
  return crc;
}

tl::expected<Header, std::string> parse_header(const std::uint8_t* data) {
  Header h;
  h.version = be16(data);
  if (h.version < 1 || h.version > 3) {
    return tl::make_unexpected("header version " + std::to_string(h.version) + " (1..3)");
  }
  if (!read_name(data + 2, 12, h.type) || h.type.empty()) {
    return tl::make_unexpected(std::string("message type is not printable ASCII"));
  }
  if (!read_name(data + 14, 20, h.device)) {
    return tl::make_unexpected("device name of a " + h.type + " is not printable ASCII");
  }
  h.timestamp = be64(data + 34);
  h.body_bytes = be64(data + 42);
  h.crc = be64(data + 50);
  return h;
}

std::uint64_t timestamp_ns(std::uint64_t igtl_timestamp) {
  const std::uint64_t seconds = igtl_timestamp >> 32;
  const std::uint64_t fraction = igtl_timestamp & 0xffffffffull;
  return seconds * 1000000000ull + ((fraction * 1000000000ull) >> 32);
}

tl::expected<Content, std::string> message_content(const Header& header,
                                                   const std::vector<std::uint8_t>& body) {
  if (header.version < 2) return Content{body.data(), body.size(), std::nullopt};
  if (body.size() < kExtendedHeaderBytes) {
    return tl::make_unexpected("version-2 body of " + std::to_string(body.size()) +
                               " bytes has no extended header");
  }
  const std::uint64_t ext = be16(body.data());
  const std::uint64_t meta_header = be16(body.data() + 2);
  const std::uint64_t meta = be32(body.data() + 4);
  if (ext < kExtendedHeaderBytes || ext + meta_header + meta > body.size()) {
    return tl::make_unexpected("extended header sizes (" + std::to_string(ext) + ", " +
                               std::to_string(meta_header) + ", " + std::to_string(meta) +
                               ") exceed the body of " + std::to_string(body.size()) + " bytes");
  }
  const std::size_t size = body.size() - ext - meta_header - meta;
  return Content{body.data() + ext, size, be32(body.data() + 8)};
}

tl::expected<RawVolume, std::string> decode_image(const std::uint8_t* content, std::size_t size,
                                                  const ImageLimits& limits) {
  if (size < kImageHeaderBytes) {
    return tl::make_unexpected("content of " + std::to_string(size) +
                               " bytes is shorter than the 72-byte image header");
  }
  const std::uint16_t version = be16(content);
  if (version != 1 && version != 2) {
    return tl::make_unexpected("image header version " + std::to_string(version) + " (1, 2)");
  }
  const ImageHeader h = read_image_header(content);
  if (auto why = check_image(h, size, limits)) return tl::make_unexpected(*why);
  RawVolume v;
  v.dims = h.size;
  v.type = h.scalar == 5 ? ProbeVoxelType::UInt16 : ProbeVoxelType::UInt8;
  if (auto why = set_geometry(h, v)) return tl::make_unexpected(*why);
  v.voxels.assign(content + kImageHeaderBytes, content + size);
  if (v.type == ProbeVoxelType::UInt16 && h.endian == 1) {  // RawVolume is little endian
    for (std::size_t i = 0; i + 1 < v.voxels.size(); i += 2)
      std::swap(v.voxels[i], v.voxels[i + 1]);
  }
  return v;
}

void MessageReader::feed(const std::uint8_t* data, std::size_t size) {
  if (consumed_ == pending_.size()) {
    pending_.clear();
    consumed_ = 0;
  } else if (consumed_ > kCompactBytes) {
    pending_.erase(pending_.begin(), pending_.begin() + static_cast<std::ptrdiff_t>(consumed_));
    consumed_ = 0;
  }
  pending_.insert(pending_.end(), data, data + size);
}

std::optional<MessageReader::Event> MessageReader::next() {
  for (;;) {
    if (lost_) return std::nullopt;
    const std::size_t available = pending_.size() - consumed_;
    const std::uint8_t* at = pending_.data() + consumed_;
    if (!header_) {
      if (available < kHeaderBytes) return std::nullopt;
      auto header = parse_header(at);
      consumed_ += kHeaderBytes;
      if (!header) {
        lost_ = true;
        return FramingLost{header.error()};
      }
      header_ = std::move(*header);
      skipping_ = header_->body_bytes > max_body_bytes_;
      skipped_bytes_ = 0;
      if (skipping_) return Oversize{*header_};
      continue;
    }
    if (skipping_) {
      const std::uint64_t take =
          std::min<std::uint64_t>(available, header_->body_bytes - skipped_bytes_);
      consumed_ += static_cast<std::size_t>(take);
      skipped_bytes_ += take;
      if (skipped_bytes_ < header_->body_bytes) return std::nullopt;
      header_.reset();
      skipping_ = false;
      continue;
    }
    const auto body_bytes = static_cast<std::size_t>(header_->body_bytes);
    if (available < body_bytes) return std::nullopt;
    Message m{std::move(*header_), std::vector<std::uint8_t>(at, at + body_bytes), false};
    header_.reset();
    consumed_ += body_bytes;
    m.crc_ok = crc64(m.body.data(), m.body.size()) == m.header.crc;
    return m;
  }
}

std::optional<MessageReader::Event> MessageReader::end_of_input() {
  std::optional<Event> event;
  const std::size_t available = pending_.size() - consumed_;
  if (lost_) {
    event.reset();
  } else if (header_) {
    event = Truncated{*header_, skipping_ ? skipped_bytes_ : available, skipping_};
  } else if (available > 0) {
    event = FramingLost{"the stream ended inside a message header (" + std::to_string(available) +
                        " of 58 bytes)"};
  }
  reset();
  return event;
}

void MessageReader::reset() {
  pending_.clear();
  consumed_ = 0;
  header_.reset();
  skipping_ = false;
  skipped_bytes_ = 0;
  lost_ = false;
}

}  // namespace sonomesh::acquire::igtl
