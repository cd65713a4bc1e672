// MetaImage (.mha attached, .mhd + .raw/.zraw detached), parsed here: the format is a short
// "Key = Value" text header ending with ElementDataFile, then raw or zlib-compressed voxels.
#include <algorithm>
#include <bit>
#include <cctype>
#include <charconv>
#include <cmath>
#include <cstring>
#include <fstream>
#include <map>
#include <vector>

#include <zlib.h>

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
  constexpr std::size_t kMaxHeader = 1 << 20;
  std::string text(kMaxHeader, '\0');
  in.read(text.data(), static_cast<std::streamsize>(text.size()));
  text.resize(static_cast<std::size_t>(in.gcount()));
  std::size_t pos = 0;
  int line_no = 0;
  while (pos < text.size()) {
    std::size_t eol = text.find('\n', pos);
    const bool last = eol == std::string::npos;
    if (last) eol = text.size();
    const std::string raw_line = text.substr(pos, eol - pos);
    pos = last ? eol : eol + 1;
    ++line_no;
    const bool printable = std::all_of(raw_line.begin(), raw_line.end(), [](char c) {
      const auto u = static_cast<unsigned char>(c);
      return u == '\t' || u == '\r' || (u >= 0x20 && u < 0x7f);
    });
    const std::string line = trim(raw_line);
    const auto eq = line.find('=');
    const std::string key = eq == std::string::npos ? std::string{} : lower(trim(line.substr(0, eq)));
    const bool key_ok = !key.empty() && std::all_of(key.begin(), key.end(), [](char c) {
      return std::isalnum(static_cast<unsigned char>(c)) || c == '_';
    });
    if (line.empty() && printable) continue;
    if (!printable || !key_ok) {
      if (header.fields.empty())
        return io_error(Code::UnknownFormat, path, "not a MetaImage file (no 'Key = Value' header)");
      return io_error(Code::BadHeader, path, "malformed header line " + std::to_string(line_no));
    }
    header.fields[key] = trim(line.substr(eq + 1));
    if (key == "elementdatafile") {  // always the last header field
      header.header_bytes = pos;
      return std::nullopt;
    }
  }
  if (header.fields.empty())
    return io_error(Code::UnknownFormat, path, "not a MetaImage file (empty header)");
  return io_error(Code::BadHeader, path,
                  text.size() == kMaxHeader ? "header longer than 1 MiB"
                                            : "header has no ElementDataFile field");
}

bool is_true(const std::string& v) {
  const std::string l = lower(v);
  return l == "true" || l == "1" || l == "yes";
}

template <typename T>
void swap_bytes(unsigned char* data, std::size_t count) {
  for (std::size_t i = 0; i < count; ++i) std::reverse(data + i * sizeof(T), data + (i + 1) * sizeof(T));
}

template <typename Src>
void to_float(const unsigned char* src, std::vector<float>& dst) {
  for (std::size_t i = 0; i < dst.size(); ++i) {
    Src v;
    std::memcpy(&v, src + i * sizeof(Src), sizeof(Src));
    dst[i] = static_cast<float>(v);
  }
}

}  // namespace

VolumeReadResult read_metaimage(const std::filesystem::path& path, const ReadOptions& options) {
  Header h;
  if (auto err = read_header(path, h)) return {Volume{}, err};
  auto fail = [&](Code code, const std::string& what) {
    return VolumeReadResult{Volume{}, io_error(code, path, what)};
  };
  if (h.has("objecttype") && lower(h.get("objecttype")) != "image")
    return fail(Code::UnknownFormat, "ObjectType is '" + h.get("objecttype") + "', not Image");
  if (!h.has("ndims")) return fail(Code::BadHeader, "no NDims field");
  int ndims = 0;
  if (!parse_number(h.get("ndims"), ndims)) return fail(Code::BadHeader, "bad NDims '" + h.get("ndims") + "'");
  if (ndims != 3) return fail(Code::BadDimensions, "NDims is " + std::to_string(ndims) + ", need 3");
  if (!h.has("dimsize")) return fail(Code::BadHeader, "no DimSize field");
  const auto dimsize = parse_numbers<long long>(h.get("dimsize"));
  if (!dimsize) return fail(Code::BadHeader, "bad DimSize '" + h.get("dimsize") + "'");
  if (dimsize->size() != 3)
    return fail(Code::SizeMismatch, "DimSize has " + std::to_string(dimsize->size()) +
                                        " values for NDims 3");
  const std::array<long long, 3> dims_ll{(*dimsize)[0], (*dimsize)[1], (*dimsize)[2]};
  if (auto err = check_dims(path, dims_ll, options)) return {Volume{}, err};

  if (!h.has("elementtype")) return fail(Code::BadHeader, "no ElementType field");
  const auto elem = element_info(h.get("elementtype"));
  if (!elem) return fail(Code::UnsupportedType, "unsupported ElementType '" + h.get("elementtype") + "'");
  if (h.has("elementnumberofchannels") && trim(h.get("elementnumberofchannels")) != "1")
    return fail(Code::UnsupportedType,
                "ElementNumberOfChannels " + h.get("elementnumberofchannels") + " (need 1)");
  if (h.has("binarydata") && !is_true(h.get("binarydata")))
    return fail(Code::UnsupportedType, "ASCII (BinaryData = False) MetaImage is not supported");

  // Geometry: rows of TransformMatrix are the directions of the index axes (ITK convention).
  auto vec3 = [&](std::initializer_list<const char*> keys, Vec3f def,
                  std::optional<VolumeIoError>& err) -> Vec3f {
    for (const char* k : keys) {
      if (!h.has(k)) continue;
      const auto v = parse_numbers<double>(h.get(k));
      if (!v || v->size() != 3 || !std::all_of(v->begin(), v->end(), [](double x) {
            return std::isfinite(static_cast<float>(x));
          })) {
        err = io_error(Code::BadHeader, path, std::string("bad ") + k + " '" + h.get(k) + "'");
        return def;
      }
      return Vec3f(static_cast<float>((*v)[0]), static_cast<float>((*v)[1]), static_cast<float>((*v)[2]));
    }
    return def;
  };
  std::optional<VolumeIoError> err;
  const Vec3f spacing = vec3({"elementspacing", "elementsize"}, Vec3f::Ones(), err);
  if (err) return {Volume{}, err};
  const Vec3f file_origin = vec3({"offset", "position", "origin"}, Vec3f::Zero(), err);
  if (err) return {Volume{}, err};
  if (!(spacing.array() > 0.0f).all())
    return fail(Code::BadHeader, "ElementSpacing must be positive");
  std::array<std::array<double, 3>, 3> dirs{};
  for (int a = 0; a < 3; ++a) dirs[a][a] = 1.0;
  for (const char* k : {"transformmatrix", "orientation", "rotation"}) {
    if (!h.has(k)) continue;
    const auto m = parse_numbers<double>(h.get(k));
    if (!m || m->size() != 9) return fail(Code::BadHeader, std::string("bad ") + k + " '" + h.get(k) + "'");
    for (int a = 0; a < 3; ++a)
      for (int c = 0; c < 3; ++c) dirs[a][c] = (*m)[3 * a + c];
    break;
  }
  AxisGeometry axes;
  if (auto e = axis_geometry(path, dirs, axes)) return {Volume{}, e};
  for (int a = 0; a < 3; ++a)
    if (std::abs(axes.spacing_mm[a] - 1.0f) > 1e-3f)
      return fail(Code::BadHeader, "TransformMatrix rows must be unit vectors");

  // Where the data is.
  const std::string data_field = h.get("elementdatafile");
  std::filesystem::path data_path = path;
  std::uintmax_t offset = h.header_bytes;
  if (data_field != "LOCAL") {
    if (data_field.empty() || data_field.find('%') != std::string::npos ||
        lower(data_field).rfind("list", 0) == 0)
      return fail(Code::BadHeader, "multi-file or empty ElementDataFile '" + data_field + "' not supported");
    data_path = std::filesystem::path(data_field);
    if (data_path.is_relative()) data_path = path.parent_path() / data_path;
    offset = 0;
  }
  const auto total = data_file_size(data_path);
  if (!total) return fail(Code::NotFound, "data file " + data_path.string() + " is missing");
  const std::size_t voxels = static_cast<std::size_t>(dims_ll[0]) * dims_ll[1] * dims_ll[2];
  const std::size_t expected = voxels * elem->bytes;
  const bool compressed = h.has("compresseddata") && is_true(h.get("compresseddata"));
  bool exact = true;
  if (h.has("headersize") && data_field != "LOCAL") {
    long long skip = 0;
    if (!parse_number(h.get("headersize"), skip) || skip < -1)
      return fail(Code::BadHeader, "bad HeaderSize '" + h.get("headersize") + "'");
    exact = false;
    if (skip == -1) offset = *total >= expected ? *total - expected : 0;  // data at the end
    else offset = static_cast<std::uintmax_t>(skip);
  }
  const std::uintmax_t available = *total > offset ? *total - offset : 0;

  std::vector<unsigned char> payload;  // compressed bytes, or raw bytes of converted types
  std::size_t stored = available;
  if (compressed) {
    if (h.has("compresseddatasize")) {
      long long csize = 0;
      if (!parse_number(h.get("compresseddatasize"), csize) || csize <= 0)
        return fail(Code::BadHeader, "bad CompressedDataSize '" + h.get("compresseddatasize") + "'");
      if (static_cast<std::uintmax_t>(csize) > available)
        return fail(Code::TruncatedData, "CompressedDataSize is " + std::to_string(csize) +
                                             " but only " + std::to_string(available) + " bytes follow");
      stored = static_cast<std::size_t>(csize);
    }
    if (stored * kMaxDeflateRatio + 1024 < expected)
      return fail(Code::TruncatedData, "compressed data of " + std::to_string(stored) +
                                           " bytes cannot hold the header's " + std::to_string(expected));
    payload.resize(stored);
    if (!read_bytes(data_path, offset, payload.data(), stored))
      return fail(Code::IoError, "cannot read data from " + data_path.string());
  } else {
    if (available < expected)
      return fail(Code::TruncatedData, "data has " + std::to_string(available) +
                                           " bytes, the header needs " + std::to_string(expected));
    if (exact && available > expected)
      return fail(Code::SizeMismatch, "data has " + std::to_string(available) +
                                          " bytes, more than the header's " + std::to_string(expected));
  }

  const Vec3i dims(static_cast<int>(dims_ll[0]), static_cast<int>(dims_ll[1]), static_cast<int>(dims_ll[2]));
  Volume volume(dims, axes.spacing_mm.cwiseProduct(spacing), file_origin, elem->target);
  std::vector<unsigned char> converted;
  unsigned char* dst = nullptr;
  if (elem->native) {
    switch (elem->target) {
      case VoxelType::UInt8: dst = volume.u8().data(); break;
      case VoxelType::UInt16: dst = reinterpret_cast<unsigned char*>(volume.u16().data()); break;
      case VoxelType::Float32: dst = reinterpret_cast<unsigned char*>(volume.f32().data()); break;
    }
  } else {
    converted.resize(expected);
    dst = converted.data();
  }
  if (compressed) {
    if (auto e = inflate_exact(path, payload, dst, expected)) return {Volume{}, e};
    payload = {};
  } else if (!read_bytes(data_path, offset, dst, expected)) {
    return fail(Code::IoError, "cannot read data from " + data_path.string());
  }

  const std::string msb_key = h.has("elementbyteordermsb") ? "elementbyteordermsb" : "binarydatabyteordermsb";
  if (h.has(msb_key) && is_true(h.get(msb_key))) {
    switch (elem->bytes) {
      case 2: swap_bytes<std::uint16_t>(dst, voxels); break;
      case 4: swap_bytes<std::uint32_t>(dst, voxels); break;
      case 8: swap_bytes<std::uint64_t>(dst, voxels); break;
      default: break;
    }
  }
  if (!elem->native) {
    const std::string& t = h.get("elementtype");
    auto& f = volume.f32();
    if (t == "MET_CHAR") to_float<std::int8_t>(dst, f);
    else if (t == "MET_SHORT") to_float<std::int16_t>(dst, f);
    else if (t == "MET_INT") to_float<std::int32_t>(dst, f);
    else if (t == "MET_UINT") to_float<std::uint32_t>(dst, f);
    else if (t == "MET_DOUBLE") to_float<double>(dst, f);
  }
  apply_geometry(volume, axes, file_origin);
  return {std::move(volume), std::nullopt};
}

std::optional<VolumeIoError> write_metaimage(const Volume& volume, const std::filesystem::path& path,
                                             Compression compression) {
  const char* met = "MET_UCHAR";
  const unsigned char* data = nullptr;
  std::size_t elem = 1;
  switch (volume.type()) {
    case VoxelType::UInt8: data = volume.u8().data(); break;
    case VoxelType::UInt16:
      met = "MET_USHORT", elem = 2;
      data = reinterpret_cast<const unsigned char*>(volume.u16().data());
      break;
    case VoxelType::Float32:
      met = "MET_FLOAT", elem = 4;
      data = reinterpret_cast<const unsigned char*>(volume.f32().data());
      break;
  }
  const std::size_t bytes = volume.voxel_count() * elem;
  std::vector<unsigned char> packed;
  if (compression == Compression::Gzip) {  // MetaImage "compressed" means a zlib stream
    uLongf size = compressBound(static_cast<uLong>(bytes));
    packed.resize(size);
    if (compress2(packed.data(), &size, data, static_cast<uLong>(bytes), 6) != Z_OK)
      return io_error(Code::Compression, path, "zlib compression failed");
    packed.resize(size);
  }
  const bool detached = lower_extension(path) == ".mhd";
  const std::filesystem::path data_path =
      std::filesystem::path(path).replace_extension(compression == Compression::Gzip ? ".zraw" : ".raw");

  auto num = [](float v) {  // shortest form of the float: 10.1, not 10.100000381469727
    char buf[32];
    const auto r = std::to_chars(buf, buf + sizeof buf, v);
    return std::string(buf, r.ptr);
  };
  auto vec = [&](const auto& v) { return num(v.x()) + " " + num(v.y()) + " " + num(v.z()); };
  std::string header = "ObjectType = Image\nNDims = 3\nBinaryData = True\nBinaryDataByteOrderMSB = False\n";
  header += std::string("CompressedData = ") + (packed.empty() ? "False" : "True") + "\n";
  if (!packed.empty()) header += "CompressedDataSize = " + std::to_string(packed.size()) + "\n";
  // TransformMatrix row a = direction of index axis a (ITK). ITK's label for the identity in an
  // LPS world is "RAI" (where the indices come from); other directions have no such label.
  const Mat3f& dir = volume.direction();
  std::string matrix;
  for (int a = 0; a < 3; ++a)
    for (int c = 0; c < 3; ++c) matrix += (matrix.empty() ? "" : " ") + num(dir(c, a));
  const bool identity = dir == Mat3f::Identity();
  header += "TransformMatrix = " + matrix + "\nOffset = " + vec(volume.origin_mm()) +
            "\nCenterOfRotation = 0 0 0\n" +
            (identity ? "AnatomicalOrientation = RAI\n" : "") + "ElementSpacing = " +
            vec(volume.spacing_mm()) + "\nDimSize = " + std::to_string(volume.dims().x()) + " " +
            std::to_string(volume.dims().y()) + " " + std::to_string(volume.dims().z()) +
            "\nElementType = " + met + "\nElementDataFile = " +
            (detached ? data_path.filename().string() : std::string("LOCAL")) + "\n";

  const unsigned char* out = packed.empty() ? data : packed.data();
  const std::size_t out_size = packed.empty() ? bytes : packed.size();
  std::ofstream hf(path, std::ios::binary | std::ios::trunc);
  if (!hf) return io_error(Code::IoError, path, "cannot open for writing");
  hf.write(header.data(), static_cast<std::streamsize>(header.size()));
  if (detached) {
    std::ofstream df(data_path, std::ios::binary | std::ios::trunc);
    if (!df) return io_error(Code::IoError, path, "cannot open data file " + data_path.string());
    df.write(reinterpret_cast<const char*>(out), static_cast<std::streamsize>(out_size));
    if (!df.flush()) return io_error(Code::IoError, path, "cannot write data file " + data_path.string());
  } else {
    hf.write(reinterpret_cast<const char*>(out), static_cast<std::streamsize>(out_size));
  }
  if (!hf.flush()) return io_error(Code::IoError, path, "cannot write");
  return std::nullopt;
}

}  // namespace sonomesh::volume::internal
