// MetaImage reader (.mha attached, .mhd + .raw/.zraw detached): the format is a short
// "Key = Value" text header ending with ElementDataFile, then raw or zlib-compressed voxels.
// The writer is metaimage_write.cpp.
#include <algorithm>
#include <bit>
#include <cctype>
#include <charconv>
#include <cmath>
#include <cstring>
#include <fstream>
#include <initializer_list>
#include <map>
#include <vector>

#include "volume/internal/header_lines.h"
#include "volume/internal/io.h"

namespace sonomesh::volume::internal {
namespace {

static_assert(std::endian::native == std::endian::little, "sonomesh assumes a little-endian host");

std::string trim(const std::string& s) {
  const auto b = s.find_first_not_of(" \t\r");
  if (b == std::string::npos) return {};
  const auto e = s.find_last_not_of(" \t\r");
  return s.substr(b, e - b + 1);
}

std::string lower(std::string s) {
  for (char& c : s) c = static_cast<char>(std::tolower(static_cast<unsigned char>(c)));
  return s;
}

std::vector<std::string> split(const std::string& s) {
  std::vector<std::string> out;
  std::size_t i = 0;
  while (i < s.size()) {
    while (i < s.size() && std::isspace(static_cast<unsigned char>(s[i]))) ++i;
    const std::size_t b = i;
    while (i < s.size() && !std::isspace(static_cast<unsigned char>(s[i]))) ++i;
    if (i > b) out.push_back(s.substr(b, i - b));
  }
  return out;
}

template <typename T>
bool parse_number(const std::string& token, T& value) {
  const char* first = token.data();
  const char* last = token.data() + token.size();
  if (first != last && *first == '+') ++first;  // from_chars rejects a leading '+'
  const auto [ptr, ec] = std::from_chars(first, last, value);
  return ec == std::errc() && ptr == last;
}

template <typename T>
std::optional<std::vector<T>> parse_numbers(const std::string& value) {
  std::vector<T> out;
  for (const auto& tok : split(value)) {
    T v{};
    if (!parse_number(tok, v)) return std::nullopt;
    out.push_back(v);
  }
  return out;
}

struct ElementInfo {
  std::size_t bytes;
  VoxelType target;
  bool native;  // stored as-is; otherwise converted to float
};

std::optional<ElementInfo> element_info(const std::string& met) {
  if (met == "MET_UCHAR") return ElementInfo{1, VoxelType::UInt8, true};
  if (met == "MET_USHORT") return ElementInfo{2, VoxelType::UInt16, true};
  if (met == "MET_FLOAT") return ElementInfo{4, VoxelType::Float32, true};
  if (met == "MET_CHAR") return ElementInfo{1, VoxelType::Float32, false};
  if (met == "MET_SHORT") return ElementInfo{2, VoxelType::Float32, false};
  if (met == "MET_INT" || met == "MET_UINT") return ElementInfo{4, VoxelType::Float32, false};
  if (met == "MET_DOUBLE") return ElementInfo{8, VoxelType::Float32, false};
  return std::nullopt;
}

struct Header {
  std::map<std::string, std::string> fields;  // lower-case key -> value
  std::uintmax_t header_bytes = 0;            // offset of LOCAL data
  bool has(const std::string& key) const { return fields.count(key) > 0; }
  const std::string& get(const std::string& key) const { return fields.at(key); }
};

std::optional<VolumeIoError> read_header(const std::filesystem::path& path, Header& header) {
  std::ifstream in(path, std::ios::binary);
  if (!in) return io_error(Code::IoError, path, "cannot open for reading");
  HeaderLines reader(in);
  std::string raw_line;
  int line_no = 0;
  while (reader.next(raw_line)) {
    ++line_no;
    const bool printable = std::all_of(raw_line.begin(), raw_line.end(), [](char c) {
      const auto u = static_cast<unsigned char>(c);
      return u == '\t' || u == '\r' || (u >= 0x20 && u < 0x7f);
    });
    const std::string line = trim(raw_line);
    const auto eq = line.find('=');
    const std::string key =
        eq == std::string::npos ? std::string{} : lower(trim(line.substr(0, eq)));
    const bool key_ok = !key.empty() && std::all_of(key.begin(), key.end(), [](char c) {
      return std::isalnum(static_cast<unsigned char>(c)) || c == '_';
    });
    if (line.empty() && printable) continue;
    if (!printable || !key_ok) {
      if (header.fields.empty())
        return io_error(Code::UnknownFormat, path,
                        "not a MetaImage file (no 'Key = Value' header)");
      return io_error(Code::BadHeader, path, "malformed header line " + std::to_string(line_no));
    }
    header.fields[key] = trim(line.substr(eq + 1));
    if (key == "elementdatafile") {  // always the last header field
      header.header_bytes = reader.consumed();
      return std::nullopt;
    }
  }
  if (header.fields.empty())
    return io_error(Code::UnknownFormat, path, "not a MetaImage file (empty header)");
  return io_error(
      Code::BadHeader, path,
      reader.at_limit() ? "header longer than 1 MiB" : "header has no ElementDataFile field");
}

bool is_true(const std::string& v) {
  const std::string l = lower(v);
  return l == "true" || l == "1" || l == "yes";
}

template <typename T>
void swap_bytes(unsigned char* data, std::size_t count) {
  for (std::size_t i = 0; i < count; ++i)
    std::reverse(data + i * sizeof(T), data + (i + 1) * sizeof(T));
}

template <typename Src>
void to_float(const unsigned char* src, std::vector<float>& dst) {
  for (std::size_t i = 0; i < dst.size(); ++i) {
    Src v;
    std::memcpy(&v, src + i * sizeof(Src), sizeof(Src));
    dst[i] = static_cast<float>(v);
  }
}

// Type and size of the voxels: NDims, DimSize (checked against the limits), ElementType.
struct Layout {
  std::array<long long, 3> dims{};
  ElementInfo elem{};
  std::size_t voxels = 0;
  std::size_t bytes = 0;  // voxels * elem.bytes, as stored
};

std::optional<VolumeIoError> parse_layout(const std::filesystem::path& path, const Header& h,
                                          const ReadOptions& options, Layout& out) {
  auto bad = [&](Code code, const std::string& what) { return io_error(code, path, what); };
  if (h.has("objecttype") && lower(h.get("objecttype")) != "image")
    return bad(Code::UnknownFormat, "ObjectType is '" + h.get("objecttype") + "', not Image");
  if (!h.has("ndims")) return bad(Code::BadHeader, "no NDims field");
  int ndims = 0;
  if (!parse_number(h.get("ndims"), ndims))
    return bad(Code::BadHeader, "bad NDims '" + h.get("ndims") + "'");
  if (ndims != 3) return bad(Code::BadDimensions, "NDims is " + std::to_string(ndims) + ", need 3");
  if (!h.has("dimsize")) return bad(Code::BadHeader, "no DimSize field");
  const auto dimsize = parse_numbers<long long>(h.get("dimsize"));
  if (!dimsize) return bad(Code::BadHeader, "bad DimSize '" + h.get("dimsize") + "'");
  if (dimsize->size() != 3)
    return bad(Code::SizeMismatch,
               "DimSize has " + std::to_string(dimsize->size()) + " values for NDims 3");
  out.dims = {(*dimsize)[0], (*dimsize)[1], (*dimsize)[2]};
  if (auto err = check_dims(path, out.dims, options)) return err;

  if (!h.has("elementtype")) return bad(Code::BadHeader, "no ElementType field");
  const auto elem = element_info(h.get("elementtype"));
  if (!elem)
    return bad(Code::UnsupportedType, "unsupported ElementType '" + h.get("elementtype") + "'");
  if (h.has("elementnumberofchannels") && trim(h.get("elementnumberofchannels")) != "1")
    return bad(Code::UnsupportedType,
               "ElementNumberOfChannels " + h.get("elementnumberofchannels") + " (need 1)");
  if (h.has("binarydata") && !is_true(h.get("binarydata")))
    return bad(Code::UnsupportedType, "ASCII (BinaryData = False) MetaImage is not supported");
  out.elem = *elem;
  out.voxels = static_cast<std::size_t>(out.dims[0]) * out.dims[1] * out.dims[2];
  out.bytes = out.voxels * elem->bytes;
  return std::nullopt;
}

// The first of `keys` present as three finite numbers into `out` (left as is if none is there).
std::optional<VolumeIoError> parse_vec3(const std::filesystem::path& path, const Header& h,
                                        std::initializer_list<const char*> keys, Vec3f& out) {
  for (const char* k : keys) {
    if (!h.has(k)) continue;
    const auto v = parse_numbers<double>(h.get(k));
    if (!v || v->size() != 3 || !std::all_of(v->begin(), v->end(), [](double x) {
          return std::isfinite(static_cast<float>(x));
        }))
      return io_error(Code::BadHeader, path, std::string("bad ") + k + " '" + h.get(k) + "'");
    out = Vec3f(static_cast<float>((*v)[0]), static_cast<float>((*v)[1]),
                static_cast<float>((*v)[2]));
    return std::nullopt;
  }
  return std::nullopt;
}

struct Geometry {
  Vec3f spacing_mm = Vec3f::Ones();
  Vec3f file_origin_mm = Vec3f::Zero();
  AxisGeometry axes;
};

// Geometry: rows of TransformMatrix are the directions of the index axes (ITK convention).
std::optional<VolumeIoError> parse_geometry(const std::filesystem::path& path, const Header& h,
                                            Geometry& out) {
  if (auto err = parse_vec3(path, h, {"elementspacing", "elementsize"}, out.spacing_mm)) return err;
  if (auto err = parse_vec3(path, h, {"offset", "position", "origin"}, out.file_origin_mm))
    return err;
  if (!(out.spacing_mm.array() > 0.0f).all())
    return io_error(Code::BadHeader, path, "ElementSpacing must be positive");
  std::array<std::array<double, 3>, 3> dirs{};
  for (int a = 0; a < 3; ++a) dirs[a][a] = 1.0;
  for (const char* k : {"transformmatrix", "orientation", "rotation"}) {
    if (!h.has(k)) continue;
    const auto m = parse_numbers<double>(h.get(k));
    if (!m || m->size() != 9)
      return io_error(Code::BadHeader, path, std::string("bad ") + k + " '" + h.get(k) + "'");
    for (int a = 0; a < 3; ++a)
      for (int c = 0; c < 3; ++c) dirs[a][c] = (*m)[3 * a + c];
    break;
  }
  if (auto err = axis_geometry(path, dirs, out.axes)) return err;
  for (int a = 0; a < 3; ++a)
    if (std::abs(out.axes.spacing_mm[a] - 1.0f) > 1e-3f)
      return io_error(Code::BadHeader, path, "TransformMatrix rows must be unit vectors");
  return std::nullopt;
}

// Where the voxels are and how many bytes they take there; checked against the layout before
// anything is allocated.
struct DataSource {
  std::filesystem::path file;
  std::uintmax_t offset = 0;
  bool compressed = false;
  std::size_t stored = 0;  // bytes to read when compressed
};

std::optional<VolumeIoError> locate_data(const std::filesystem::path& path, const Header& h,
                                         std::size_t expected, DataSource& out) {
  auto bad = [&](Code code, const std::string& what) { return io_error(code, path, what); };
  const std::string& field = h.get("elementdatafile");
  out.file = path;
  out.offset = h.header_bytes;
  if (field != "LOCAL") {
    if (field.empty() || field.find('%') != std::string::npos || lower(field).rfind("list", 0) == 0)
      return bad(Code::BadHeader,
                 "multi-file or empty ElementDataFile '" + field + "' not supported");
    out.file = std::filesystem::path(field);
    if (out.file.is_relative()) out.file = path.parent_path() / out.file;
    out.offset = 0;
  }
  const auto total = data_file_size(out.file);
  if (!total) return bad(Code::NotFound, "data file " + out.file.string() + " is missing");
  bool exact = true;
  if (h.has("headersize") && field != "LOCAL") {
    long long skip = 0;
    if (!parse_number(h.get("headersize"), skip) || skip < -1)
      return bad(Code::BadHeader, "bad HeaderSize '" + h.get("headersize") + "'");
    exact = false;
    if (skip == -1)
      out.offset = *total >= expected ? *total - expected : 0;  // data at the end
    else
      out.offset = static_cast<std::uintmax_t>(skip);
  }
  const std::uintmax_t available = *total > out.offset ? *total - out.offset : 0;
  out.compressed = h.has("compresseddata") && is_true(h.get("compresseddata"));
  if (!out.compressed) {
    if (available < expected)
      return bad(Code::TruncatedData, "data has " + std::to_string(available) +
                                          " bytes, the header needs " + std::to_string(expected));
    if (exact && available > expected)
      return bad(Code::SizeMismatch, "data has " + std::to_string(available) +
                                         " bytes, more than the header's " +
                                         std::to_string(expected));
    return std::nullopt;
  }
  out.stored = available;
  if (h.has("compresseddatasize")) {
    long long csize = 0;
    if (!parse_number(h.get("compresseddatasize"), csize) || csize <= 0)
      return bad(Code::BadHeader, "bad CompressedDataSize '" + h.get("compresseddatasize") + "'");
    if (static_cast<std::uintmax_t>(csize) > available)
      return bad(Code::TruncatedData, "CompressedDataSize is " + std::to_string(csize) +
                                          " but only " + std::to_string(available) +
                                          " bytes follow");
    out.stored = static_cast<std::size_t>(csize);
  }
  if (out.stored * kMaxDeflateRatio + 1024 < expected)
    return bad(Code::TruncatedData, "compressed data of " + std::to_string(out.stored) +
                                        " bytes cannot hold the header's " +
                                        std::to_string(expected));
  return std::nullopt;
}

// The stored bytes (inflated if compressed), byte-swapped to little endian if the file is MSB.
std::optional<VolumeIoError> read_stored(const std::filesystem::path& path, const Header& h,
                                         const Layout& layout, const DataSource& src,
                                         unsigned char* dst) {
  if (src.compressed) {
    std::vector<unsigned char> payload(src.stored);
    if (!read_bytes(src.file, src.offset, payload.data(), src.stored))
      return io_error(Code::IoError, path, "cannot read data from " + src.file.string());
    if (auto e = inflate_exact(path, payload, dst, layout.bytes)) return e;
  } else if (!read_bytes(src.file, src.offset, dst, layout.bytes)) {
    return io_error(Code::IoError, path, "cannot read data from " + src.file.string());
  }
  const std::string msb_key =
      h.has("elementbyteordermsb") ? "elementbyteordermsb" : "binarydatabyteordermsb";
  if (h.has(msb_key) && is_true(h.get(msb_key))) {
    switch (layout.elem.bytes) {
      case 2:
        swap_bytes<std::uint16_t>(dst, layout.voxels);
        break;
      case 4:
        swap_bytes<std::uint32_t>(dst, layout.voxels);
        break;
      case 8:
        swap_bytes<std::uint64_t>(dst, layout.voxels);
        break;
      default:
        break;
    }
  }
  return std::nullopt;
}

// Reads the voxels into `volume` (allocated by the caller with the layout's dims and type):
// native types straight into it, the others through a byte buffer converted to float.
std::optional<VolumeIoError> read_voxels(const std::filesystem::path& path, const Header& h,
                                         const Layout& layout, const DataSource& src,
                                         Volume& volume) {
  if (!layout.elem.native) {
    std::vector<unsigned char> stored(layout.bytes);
    if (auto e = read_stored(path, h, layout, src, stored.data())) return e;
    const std::string& t = h.get("elementtype");
    auto& f = volume.f32();
    if (t == "MET_CHAR")
      to_float<std::int8_t>(stored.data(), f);
    else if (t == "MET_SHORT")
      to_float<std::int16_t>(stored.data(), f);
    else if (t == "MET_INT")
      to_float<std::int32_t>(stored.data(), f);
    else if (t == "MET_UINT")
      to_float<std::uint32_t>(stored.data(), f);
    else if (t == "MET_DOUBLE")
      to_float<double>(stored.data(), f);
    return std::nullopt;
  }
  unsigned char* dst = nullptr;
  switch (layout.elem.target) {
    case VoxelType::UInt8:
      dst = volume.u8().data();
      break;
    case VoxelType::UInt16:
      dst = reinterpret_cast<unsigned char*>(volume.u16().data());
      break;
    case VoxelType::Float32:
      dst = reinterpret_cast<unsigned char*>(volume.f32().data());
      break;
  }
  return read_stored(path, h, layout, src, dst);
}

}  // namespace

VolumeReadResult read_metaimage(const std::filesystem::path& path, const ReadOptions& options) {
  Header h;
  Layout layout;
  Geometry geometry;
  DataSource src;
  std::optional<VolumeIoError> err = read_header(path, h);
  if (!err) err = parse_layout(path, h, options, layout);
  if (!err) err = parse_geometry(path, h, geometry);
  if (!err) err = locate_data(path, h, layout.bytes, src);
  if (err) return {Volume{}, err};
  const Vec3i dims(static_cast<int>(layout.dims[0]), static_cast<int>(layout.dims[1]),
                   static_cast<int>(layout.dims[2]));
  Volume volume(dims, geometry.axes.spacing_mm.cwiseProduct(geometry.spacing_mm),
                geometry.file_origin_mm, layout.elem.target);
  if (auto e = read_voxels(path, h, layout, src, volume)) return {Volume{}, e};
  apply_geometry(volume, geometry.axes, geometry.file_origin_mm);
  return {std::move(volume), std::nullopt};
}

}  // namespace sonomesh::volume::internal
