// NRRD (.nrrd attached, .nhdr detached) through Teem.
//
// Teem reports errors through biff, a process-global message stack that is not thread-safe, so
// every Teem call runs under one mutex. Teem never exits on I/O errors; it returns non-zero and
// leaves the text in biff. Its reader allocates the whole payload from the header's sizes, so the
// header is read first (nrrdIoStateSkipData) and validated against ReadOptions and the size of the
// data on disk before the real read.
#include <algorithm>
#include <charconv>
#include <climits>
#include <cmath>
#include <cstdlib>
#include <cstring>
#include <fstream>
#include <memory>
#include <mutex>

#include <teem/nrrd.h>

#include "volume/internal/io.h"

namespace sonomesh::volume::internal {
namespace {

std::mutex& teem_mutex() {
  static std::mutex m;
  return m;
}

std::string biff_message() {
  char* err = biffGetDone(NRRD);
  if (!err) return "unknown Teem error";
  std::string msg(err);
  std::free(err);
  // biff stacks one line per Teem function ("[nrrd] nrrdLoad: ..."); the innermost (last) line
  // names the actual problem, the outer ones only the call chain.
  while (!msg.empty() && (msg.back() == '\n' || msg.back() == ' ')) msg.pop_back();
  const auto last = msg.rfind('\n');
  std::string inner = last == std::string::npos ? msg : msg.substr(last + 1);
  if (inner.rfind("[nrrd] ", 0) == 0) inner = inner.substr(7);
  return inner;
}

struct NrrdDeleter {
  void operator()(Nrrd* n) const { nrrdNuke(n); }
};
struct NixDeleter {  // for wrapped data we do not own
  void operator()(Nrrd* n) const { nrrdNix(n); }
};
struct IoStateDeleter {
  void operator()(NrrdIoState* n) const { nrrdIoStateNix(n); }
};
using NrrdPtr = std::unique_ptr<Nrrd, NrrdDeleter>;
using IoStatePtr = std::unique_ptr<NrrdIoState, IoStateDeleter>;

// What a quick look at the header text tells before Teem parses it.
struct HeaderScan {
  std::uintmax_t header_bytes = 0;  // offset of the attached data (after the blank line)
  bool has_end = false;             // saw the blank line that ends the header
  std::string data_file;            // "data file:" value, if any
};

std::optional<VolumeIoError> scan_header(const std::filesystem::path& path, HeaderScan& scan) {
  std::ifstream in(path, std::ios::binary);
  if (!in) return io_error(Code::IoError, path, "cannot open for reading");
  constexpr std::size_t kMaxHeader = 1 << 20;
  std::string text(kMaxHeader, '\0');
  in.read(text.data(), static_cast<std::streamsize>(text.size()));
  text.resize(static_cast<std::size_t>(in.gcount()));
  if (text.rfind("NRRD000", 0) != 0)
    return io_error(Code::UnknownFormat, path, "not a NRRD file (no NRRD000x magic)");
  std::size_t pos = 0;
  while (pos < text.size()) {
    std::size_t eol = text.find('\n', pos);
    if (eol == std::string::npos) break;  // header of a detached file may end at EOF
    std::string line = text.substr(pos, eol - pos);
    if (!line.empty() && line.back() == '\r') line.pop_back();
    pos = eol + 1;
    if (line.empty()) {
      scan.has_end = true;
      scan.header_bytes = pos;
      break;
    }
    if (line.rfind("type:", 0) == 0) {
      std::string value = line.substr(5);
      value.erase(0, value.find_first_not_of(' '));
      while (!value.empty() && value.back() == ' ') value.pop_back();
      if (airEnumVal(nrrdType, value.c_str()) == nrrdTypeUnknown)
        return io_error(Code::UnsupportedType, path, "unknown voxel type '" + value + "'");
    }
    for (const char* key : {"data file:", "datafile:"})
      if (line.rfind(key, 0) == 0) {
        scan.data_file = line.substr(std::strlen(key));
        scan.data_file.erase(0, scan.data_file.find_first_not_of(' '));
        while (!scan.data_file.empty() && scan.data_file.back() == ' ') scan.data_file.pop_back();
      }
    for (char c : line)
      if (c == '\0') return io_error(Code::BadHeader, path, "binary bytes inside the header");
  }
  if (!scan.has_end) {
    if (text.size() == kMaxHeader) return io_error(Code::BadHeader, path, "header longer than 1 MiB");
    scan.header_bytes = text.size();
  }
  return std::nullopt;
}

// Teem's voxel types: the three native ones, others converted to float.
std::optional<VoxelType> target_type(int nrrd_type) {
  switch (nrrd_type) {
    case nrrdTypeUChar: return VoxelType::UInt8;
    case nrrdTypeUShort: return VoxelType::UInt16;
    case nrrdTypeFloat:
    case nrrdTypeChar:
    case nrrdTypeShort:
    case nrrdTypeInt:
    case nrrdTypeUInt:
    case nrrdTypeDouble: return VoxelType::Float32;
    default: return std::nullopt;
  }
}

// The double whose shortest decimal form is the float's (10.1f -> 10.1, not 10.100000381...), so
// headers show the numbers the caller meant.
double decimal(float v) {
  char buf[32];
  const auto end = std::to_chars(buf, buf + sizeof buf, v).ptr;
  double d = v;
  std::from_chars(buf, end, d);
  return d;
}

template <typename Src>
void convert_to_float(const void* src, std::vector<float>& dst) {
  const auto* s = static_cast<const Src*>(src);
  for (std::size_t i = 0; i < dst.size(); ++i) dst[i] = static_cast<float>(s[i]);
}

// Geometry from the parsed header; converts RAS/LAS spaces to LPS, the space this project (and
// ITK) uses and writes.
std::optional<VolumeIoError> geometry(const std::filesystem::path& path, const Nrrd* n,
                                      AxisGeometry& axes, Vec3f& origin) {
  std::array<std::array<double, 3>, 3> dirs{};
  std::array<double, 3> org{0.0, 0.0, 0.0};
  if (n->spaceDim == 3) {
    for (int a = 0; a < 3; ++a)
      for (int c = 0; c < 3; ++c) dirs[a][c] = n->axis[a].spaceDirection[c];
    for (int c = 0; c < 3; ++c) org[c] = std::isfinite(n->spaceOrigin[c]) ? n->spaceOrigin[c] : 0.0;
    const std::array<double, 3> sign = n->space == nrrdSpaceRightAnteriorSuperior
                                           ? std::array<double, 3>{-1, -1, 1}
                                       : n->space == nrrdSpaceLeftAnteriorSuperior
                                           ? std::array<double, 3>{1, -1, 1}
                                           : std::array<double, 3>{1, 1, 1};
    for (int c = 0; c < 3; ++c) {
      org[c] *= sign[c];
      for (int a = 0; a < 3; ++a) dirs[a][c] *= sign[c];
    }
  } else if (n->spaceDim == 0) {
    for (int a = 0; a < 3; ++a) {
      const double s = n->axis[a].spacing;
      dirs[a][a] = std::isfinite(s) && s != 0.0 ? s : 1.0;
    }
  } else {
    return io_error(Code::UnsupportedOrientation, path,
                    "space dimension " + std::to_string(n->spaceDim) + " (need 3)");
  }
  if (auto err = axis_geometry(path, dirs, axes)) return err;
  origin = Vec3f(static_cast<float>(org[0]), static_cast<float>(org[1]), static_cast<float>(org[2]));
  if (!origin.allFinite()) return io_error(Code::BadHeader, path, "space origin out of range");
  return std::nullopt;
}

}  // namespace

VolumeReadResult read_nrrd(const std::filesystem::path& path, const ReadOptions& options) {
  HeaderScan scan;
  if (auto err = scan_header(path, scan)) return {Volume{}, err};

  // Teem opens a single detached data file even when skipping data; say clearly that it is missing.
  if (!scan.data_file.empty() && scan.data_file.find(' ') == std::string::npos &&
      scan.data_file.find('%') == std::string::npos && scan.data_file != "LIST") {
    std::filesystem::path data = scan.data_file;
    if (data.is_relative()) data = path.parent_path() / data;
    if (!data_file_size(data))
      return {Volume{}, io_error(Code::NotFound, path, "data file " + data.string() + " is missing")};
  }

  std::lock_guard<std::mutex> lock(teem_mutex());
  nrrdStateVerboseIO = 0;  // library code stays quiet; errors come back through biff
  // Pass 1: header only.
  NrrdPtr header(nrrdNew());
  IoStatePtr hio(nrrdIoStateNew());
  nrrdIoStateSet(hio.get(), nrrdIoStateSkipData, AIR_TRUE);
  if (nrrdLoad(header.get(), path.c_str(), hio.get()))
    return {Volume{}, io_error(Code::BadHeader, path, biff_message())};
  const Nrrd* h = header.get();
  if (h->dim != 3)
    return {Volume{}, io_error(Code::BadDimensions, path,
                               "has " + std::to_string(h->dim) + " dimensions, need 3")};
  const auto type = target_type(h->type);
  if (!type)
    return {Volume{}, io_error(Code::UnsupportedType, path,
                               std::string("unsupported voxel type ") + airEnumStr(nrrdType, h->type))};
  const std::array<long long, 3> dims_ll{static_cast<long long>(std::min<size_t>(h->axis[0].size, LLONG_MAX)),
                                         static_cast<long long>(std::min<size_t>(h->axis[1].size, LLONG_MAX)),
                                         static_cast<long long>(std::min<size_t>(h->axis[2].size, LLONG_MAX))};
  if (auto err = check_dims(path, dims_ll, options)) return {Volume{}, err};
  AxisGeometry axes;
  Vec3f origin;
  if (auto err = geometry(path, h, axes, origin)) return {Volume{}, err};

  // Is the payload on disk big enough for what the header announces?
  const std::uintmax_t voxels = static_cast<std::uintmax_t>(dims_ll[0]) * dims_ll[1] * dims_ll[2];
  const std::uintmax_t expected = voxels * nrrdTypeSize[h->type];
  const NrrdEncoding* enc = hio->encoding;
  std::uintmax_t available = 0;
  std::filesystem::path first_data = path;  // where the payload starts (attached: after header)
  std::uintmax_t first_offset = scan.header_bytes;
  bool exact = hio->lineSkip == 0 && hio->byteSkip == 0 && hio->dataFSkip == nullptr;
  const unsigned files = hio->dataFNArr ? hio->dataFNArr->len : 0;
  if (files == 0 && !hio->dataFNFormat) {
    const auto size = data_file_size(path);
    if (!size) return {Volume{}, io_error(Code::IoError, path, "cannot stat")};
    available = *size > scan.header_bytes ? *size - scan.header_bytes : 0;
  } else if (files > 0) {
    const std::filesystem::path dir = hio->path ? std::filesystem::path(hio->path) : path.parent_path();
    for (unsigned f = 0; f < files; ++f) {
      std::filesystem::path data = hio->dataFN[f];
      if (data.is_relative()) data = dir / data;
      const auto size = data_file_size(data);
      if (!size)
        return {Volume{}, io_error(Code::NotFound, path, "data file " + data.string() + " is missing")};
      available += *size;
      if (f == 0) first_data = data, first_offset = 0;
    }
  } else {
    exact = false;
    available = expected;  // numbered data files (%d pattern): Teem checks them itself
  }
  if (enc == nrrdEncodingRaw) {
    if (available < expected)
      return {Volume{}, io_error(Code::TruncatedData, path,
                                 "data has " + std::to_string(available) + " bytes, the header needs " +
                                     std::to_string(expected))};
    if (exact && available > expected)
      return {Volume{}, io_error(Code::SizeMismatch, path,
                                 "data has " + std::to_string(available) +
                                     " bytes, more than the header's " + std::to_string(expected))};
  } else if (enc == nrrdEncodingGzip || enc == nrrdEncodingBzip2) {
    if (!enc->available())
      return {Volume{}, io_error(Code::Compression, path,
                                 std::string(enc->name) + " encoding not available in this Teem")};
    // zlib's gz reader passes data without a gzip header through unchanged, so check the magic.
    if (enc == nrrdEncodingGzip && exact && available >= 2) {
      unsigned char magic[2] = {0, 0};
      std::ifstream in(first_data, std::ios::binary);
      in.seekg(static_cast<std::streamoff>(first_offset));
      in.read(reinterpret_cast<char*>(magic), 2);
      if (magic[0] != 0x1f || magic[1] != 0x8b)
        return {Volume{}, io_error(Code::Compression, path, "gzip encoding, but the data is not gzip")};
    }
    if (available * kMaxDeflateRatio + 1024 < expected)
      return {Volume{}, io_error(Code::TruncatedData, path,
                                 "compressed data of " + std::to_string(available) +
                                     " bytes cannot hold the header's " + std::to_string(expected))};
  } else if (available < voxels) {  // text encodings need at least a character per value
    return {Volume{}, io_error(Code::TruncatedData, path,
                               "data too short for " + std::to_string(voxels) + " values")};
  }

  // Pass 2: the real read, now that the allocation it makes is known to be sane.
  NrrdPtr full(nrrdNew());
  IoStatePtr fio(nrrdIoStateNew());
  if (nrrdLoad(full.get(), path.c_str(), fio.get())) {
    const Code code = (enc == nrrdEncodingGzip || enc == nrrdEncodingBzip2) ? Code::Compression
                      : enc == nrrdEncodingRaw                             ? Code::TruncatedData
                                                                           : Code::BadHeader;
    return {Volume{}, io_error(code, path, "reading data: " + biff_message())};
  }
  const Nrrd* n = full.get();
  if (n->type != h->type || n->axis[0].size != h->axis[0].size ||
      n->axis[1].size != h->axis[1].size || n->axis[2].size != h->axis[2].size || !n->data)
    return {Volume{}, io_error(Code::IoError, path, "file changed while reading")};

  const Vec3i dims(static_cast<int>(dims_ll[0]), static_cast<int>(dims_ll[1]), static_cast<int>(dims_ll[2]));
  Volume volume(dims, axes.spacing_mm, origin, *type);
  switch (n->type) {
    case nrrdTypeUChar: std::memcpy(volume.u8().data(), n->data, expected); break;
    case nrrdTypeUShort: std::memcpy(volume.u16().data(), n->data, expected); break;
    case nrrdTypeFloat: std::memcpy(volume.f32().data(), n->data, expected); break;
    case nrrdTypeChar: convert_to_float<signed char>(n->data, volume.f32()); break;
    case nrrdTypeShort: convert_to_float<short>(n->data, volume.f32()); break;
    case nrrdTypeInt: convert_to_float<int>(n->data, volume.f32()); break;
    case nrrdTypeUInt: convert_to_float<unsigned int>(n->data, volume.f32()); break;
    case nrrdTypeDouble: convert_to_float<double>(n->data, volume.f32()); break;
    default: break;
  }
  full.reset();
  apply_flips(volume, axes.flip, origin);
  return {std::move(volume), std::nullopt};
}

std::optional<VolumeIoError> write_nrrd(const Volume& volume, const std::filesystem::path& path,
                                        Compression compression) {
  int type = nrrdTypeFloat;
  void* data = nullptr;
  // Teem wraps the buffer without copying and only reads it when saving.
  switch (volume.type()) {
    case VoxelType::UInt8: type = nrrdTypeUChar; data = const_cast<std::uint8_t*>(volume.u8().data()); break;
    case VoxelType::UInt16: type = nrrdTypeUShort; data = const_cast<std::uint16_t*>(volume.u16().data()); break;
    case VoxelType::Float32: type = nrrdTypeFloat; data = const_cast<float*>(volume.f32().data()); break;
  }
  const Vec3i& d = volume.dims();
  const Vec3f& s = volume.spacing_mm();
  const Vec3f& o = volume.origin_mm();

  std::lock_guard<std::mutex> lock(teem_mutex());
  std::unique_ptr<Nrrd, NixDeleter> nrrd(nrrdNew());
  if (nrrdWrap_va(nrrd.get(), data, type, 3, static_cast<size_t>(d.x()), static_cast<size_t>(d.y()),
                  static_cast<size_t>(d.z())))
    return io_error(Code::IoError, path, biff_message());
  // "left-posterior-superior" is what 3D Slicer, ITK and pynrrd expect for a world space in mm.
  if (nrrdSpaceSet(nrrd.get(), nrrdSpaceLeftPosteriorSuperior))
    return io_error(Code::IoError, path, biff_message());
  const double origin[3] = {decimal(o.x()), decimal(o.y()), decimal(o.z())};
  if (nrrdSpaceOriginSet(nrrd.get(), origin)) return io_error(Code::IoError, path, biff_message());
  double dx[NRRD_SPACE_DIM_MAX] = {decimal(s.x()), 0, 0}, dy[NRRD_SPACE_DIM_MAX] = {0, decimal(s.y()), 0},
         dz[NRRD_SPACE_DIM_MAX] = {0, 0, decimal(s.z())};
  nrrdAxisInfoSet_va(nrrd.get(), nrrdAxisInfoSpaceDirection, dx, dy, dz);
  nrrdAxisInfoSet_va(nrrd.get(), nrrdAxisInfoKind, nrrdKindSpace, nrrdKindSpace, nrrdKindSpace);
  nrrdAxisInfoSet_va(nrrd.get(), nrrdAxisInfoCenter, nrrdCenterCell, nrrdCenterCell, nrrdCenterCell);

  IoStatePtr nio(nrrdIoStateNew());
  if (compression == Compression::Gzip) {
    if (!nrrdEncodingGzip->available())
      return io_error(Code::Compression, path, "gzip encoding not available in this Teem");
    nrrdIoStateEncodingSet(nio.get(), nrrdEncodingGzip);
    nrrdIoStateSet(nio.get(), nrrdIoStateZlibLevel, 6);
  } else {
    nrrdIoStateEncodingSet(nio.get(), nrrdEncodingRaw);
  }
  if (nrrdSave(path.c_str(), nrrd.get(), nio.get()))
    return io_error(Code::IoError, path, "cannot write: " + biff_message());
  return std::nullopt;
}

}  // namespace sonomesh::volume::internal
