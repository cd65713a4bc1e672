// NRRD (.nrrd attached, .nhdr detached) through Teem.
//
// Teem reports errors through biff, a process-global message stack that is not thread-safe, so
// every Teem call runs under one mutex. Teem never exits on I/O errors; it returns non-zero and
// leaves the text in biff. Its reader allocates the whole payload from the header's sizes, so the
// header is read first (nrrdIoStateSkipData) and validated against ReadOptions and the size of the
// data on disk before the payload is read. Teem is handed only what nrrd_scan.h validated, through
// a short path; raw and gzip payloads in one file are read here (Teem's gzip reader leaks its
// stream state on corrupt data), other layouts by Teem.
#include <teem/nrrd.h>

#include <algorithm>
#include <charconv>
#include <climits>
#include <cmath>
#include <cstdlib>
#include <cstring>
#include <fstream>
#include <memory>
#include <mutex>

#include "volume/internal/io.h"
#include "volume/internal/nrrd_scan.h"

namespace sonomesh::volume::internal {
namespace {

std::mutex& teem_mutex() {
  static std::mutex m;
  return m;
}

std::string biff_message(const ShortPath* short_path = nullptr) {
  char* err = biffGetDone(NRRD);
  if (!err) return "unknown Teem error";
  std::string msg(err);
  std::free(err);
  if (short_path) msg = short_path->restore(std::move(msg));
  // biff stacks one line per Teem function ("[nrrd] nrrdLoad: ..."); the innermost (last) line
  // names the actual problem, the outer ones only the call chain.
  while (!msg.empty() && (msg.back() == '\n' || msg.back() == ' ')) msg.pop_back();
  const auto last = msg.rfind('\n');
  std::string inner = last == std::string::npos ? msg : msg.substr(last + 1);
  if (inner.rfind("[nrrd] ", 0) == 0) inner = inner.substr(7);
  return inner;
}

// Leaves biff's process-global error state empty on every path out of a Teem call sequence
// (messages not collected by biff_message would otherwise stay allocated until the next error).
struct BiffGuard {
  ~BiffGuard() {
    if (biffCheck(NRRD)) biffDone(NRRD);
  }
};

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

// Teem's voxel types: the three native ones, others converted to float.
std::optional<VoxelType> target_type(int nrrd_type) {
  switch (nrrd_type) {
    case nrrdTypeUChar:
      return VoxelType::UInt8;
    case nrrdTypeUShort:
      return VoxelType::UInt16;
    case nrrdTypeFloat:
    case nrrdTypeChar:
    case nrrdTypeShort:
    case nrrdTypeInt:
    case nrrdTypeUInt:
    case nrrdTypeDouble:
      return VoxelType::Float32;
    default:
      return std::nullopt;
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
    const std::array<double, 3> sign =
        n->space == nrrdSpaceRightAnteriorSuperior  ? std::array<double, 3>{-1, -1, 1}
        : n->space == nrrdSpaceLeftAnteriorSuperior ? std::array<double, 3>{1, -1, 1}
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
  origin =
      Vec3f(static_cast<float>(org[0]), static_cast<float>(org[1]), static_cast<float>(org[2]));
  if (!origin.allFinite()) return io_error(Code::BadHeader, path, "space origin out of range");
  return std::nullopt;
}

// Where the payload is, and whether the bytes on disk can hold what the header announces.
struct Payload {
  std::filesystem::path file;  // first (or only) data file
  std::uintmax_t offset = 0;   // where the data starts in it
  std::uintmax_t available = 0;
  bool exact = true;   // one file (or attached), no skips: the size must match exactly
  bool single = true;  // at most one data file
};

std::optional<VolumeIoError> locate_payload(const std::filesystem::path& path,
                                            const HeaderScan& scan, const NrrdIoState* hio,
                                            Payload& out) {
  out.file = path;
  out.offset = scan.header_bytes;
  out.exact = hio->lineSkip == 0 && hio->byteSkip == 0 && hio->dataFSkip == nullptr;
  const unsigned files = hio->dataFNArr ? hio->dataFNArr->len : 0;
  out.single = files <= 1 && !hio->dataFNFormat;
  if (files == 0 && !hio->dataFNFormat) {
    const auto size = data_file_size(path);
    if (!size) return io_error(Code::IoError, path, "cannot stat");
    out.available = *size > scan.header_bytes ? *size - scan.header_bytes : 0;
    return std::nullopt;
  }
  if (files == 0) {  // numbered data files (%d pattern): Teem checks them itself
    out.exact = false;
    out.available = UINTMAX_MAX;
    return std::nullopt;
  }
  // hio->path is the short /proc/self/fd/N directory; resolve against the real one.
  for (unsigned f = 0; f < files; ++f) {
    std::filesystem::path data = hio->dataFN[f];
    if (data.is_relative()) data = path.parent_path() / data;
    const auto size = data_file_size(data);
    if (!size) return io_error(Code::NotFound, path, "data file " + data.string() + " is missing");
    out.available += *size;
    if (f == 0) out.file = data, out.offset = 0;
  }
  return std::nullopt;
}

std::optional<VolumeIoError> check_payload_size(const std::filesystem::path& path,
                                                const NrrdEncoding* enc, const Payload& p,
                                                std::uintmax_t voxels, std::uintmax_t expected) {
  if (enc == nrrdEncodingRaw) {
    if (p.available < expected)
      return io_error(Code::TruncatedData, path,
                      "data has " + std::to_string(p.available) + " bytes, the header needs " +
                          std::to_string(expected));
    if (p.exact && p.available > expected)
      return io_error(Code::SizeMismatch, path,
                      "data has " + std::to_string(p.available) +
                          " bytes, more than the header's " + std::to_string(expected));
  } else if (enc == nrrdEncodingGzip || enc == nrrdEncodingBzip2) {
    if (!enc->available())
      return io_error(Code::Compression, path,
                      std::string(enc->name) + " encoding not available in this Teem");
    if (p.available != UINTMAX_MAX && p.available * kMaxDeflateRatio + 1024 < expected)
      return io_error(Code::TruncatedData, path,
                      "compressed data of " + std::to_string(p.available) +
                          " bytes cannot hold the header's " + std::to_string(expected));
  } else if (p.available < voxels) {  // text encodings need at least a character per value
    return io_error(Code::TruncatedData, path,
                    "data too short for " + std::to_string(voxels) + " values");
  }
  return std::nullopt;
}

// Raw or gzip data in one file, read here into `dst` (expected bytes, file byte order).
std::optional<VolumeIoError> read_payload(const std::filesystem::path& path, const Payload& p,
                                          bool gzip, unsigned char* dst, std::size_t expected) {
  if (!gzip) {
    if (!read_bytes(p.file, p.offset, dst, expected))
      return io_error(
          Code::TruncatedData, path,
          "cannot read " + std::to_string(expected) + " bytes of data from " + p.file.string());
    return std::nullopt;
  }
  std::vector<unsigned char> packed(static_cast<std::size_t>(p.available));
  if (!read_bytes(p.file, p.offset, packed.data(), packed.size()))
    return io_error(Code::IoError, path, "cannot read data from " + p.file.string());
  // zlib would pass data without a gzip header through unchanged, so check the magic.
  if (packed.size() < 2 || packed[0] != 0x1f || packed[1] != 0x8b)
    return io_error(Code::Compression, path, "gzip encoding, but the data is not gzip");
  return inflate_exact(path, packed, dst, expected);
}

void swap_endian(unsigned char* data, std::size_t bytes, std::size_t size) {
  if (size < 2) return;
  for (std::size_t i = 0; i + size <= bytes; i += size) std::reverse(data + i, data + i + size);
}

void fill_volume(Volume& volume, int nrrd_type, const void* data, std::size_t bytes) {
  switch (nrrd_type) {
    case nrrdTypeUChar:
      std::memcpy(volume.u8().data(), data, bytes);
      break;
    case nrrdTypeUShort:
      std::memcpy(volume.u16().data(), data, bytes);
      break;
    case nrrdTypeFloat:
      std::memcpy(volume.f32().data(), data, bytes);
      break;
    case nrrdTypeChar:
      convert_to_float<signed char>(data, volume.f32());
      break;
    case nrrdTypeShort:
      convert_to_float<short>(data, volume.f32());
      break;
    case nrrdTypeInt:
      convert_to_float<int>(data, volume.f32());
      break;
    case nrrdTypeUInt:
      convert_to_float<unsigned int>(data, volume.f32());
      break;
    case nrrdTypeDouble:
      convert_to_float<double>(data, volume.f32());
      break;
    default:
      break;
  }
}

// Other layouts (text, bzip2, skips, several data files): Teem reads them, then checks that the
// file did not change since the header pass.
std::optional<VolumeIoError> teem_payload(const std::filesystem::path& path, const ShortPath& sp,
                                          const Nrrd* h, const NrrdEncoding* enc, Volume& volume,
                                          std::size_t expected) {
  NrrdPtr full(nrrdNew());
  IoStatePtr fio(nrrdIoStateNew());
  if (nrrdLoad(full.get(), sp.path().c_str(), fio.get())) {
    const Code code = (enc == nrrdEncodingGzip || enc == nrrdEncodingBzip2) ? Code::Compression
                      : enc == nrrdEncodingRaw                              ? Code::TruncatedData
                                                                            : Code::BadHeader;
    return io_error(code, path, "reading data: " + biff_message(&sp));
  }
  const Nrrd* n = full.get();
  if (n->type != h->type || n->axis[0].size != h->axis[0].size ||
      n->axis[1].size != h->axis[1].size || n->axis[2].size != h->axis[2].size || !n->data)
    return io_error(Code::IoError, path, "file changed while reading");
  fill_volume(volume, n->type, n->data, expected);
  return std::nullopt;
}

std::optional<VolumeIoError> check_header(const std::filesystem::path& path, const Nrrd* h,
                                          const ReadOptions& options, Vec3i& dims) {
  if (h->dim != 3)
    return io_error(Code::BadDimensions, path,
                    "has " + std::to_string(h->dim) + " dimensions, need 3");
  if (!target_type(h->type))
    return io_error(Code::UnsupportedType, path,
                    std::string("unsupported voxel type ") + airEnumStr(nrrdType, h->type));
  std::array<long long, 3> dims_ll{};
  for (int a = 0; a < 3; ++a)
    dims_ll[a] = static_cast<long long>(std::min<size_t>(h->axis[a].size, LLONG_MAX));
  if (auto err = check_dims(path, dims_ll, options)) return err;
  dims = Vec3i(static_cast<int>(dims_ll[0]), static_cast<int>(dims_ll[1]),
               static_cast<int>(dims_ll[2]));
  return std::nullopt;
}

// Teem opens a single detached data file even when skipping data; say clearly that it is missing.
std::optional<VolumeIoError> check_data_file(const std::filesystem::path& path,
                                             const HeaderScan& scan) {
  if (scan.data_file.empty() || scan.data_file.find(' ') != std::string::npos ||
      scan.data_file.find('%') != std::string::npos || scan.data_file == "LIST")
    return std::nullopt;
  std::filesystem::path data = scan.data_file;
  if (data.is_relative()) data = path.parent_path() / data;
  if (!data_file_size(data))
    return io_error(Code::NotFound, path, "data file " + data.string() + " is missing");
  return std::nullopt;
}

}  // namespace

VolumeReadResult read_nrrd(const std::filesystem::path& path, const ReadOptions& options) {
  HeaderScan scan;
  if (auto err = scan_nrrd_header(path, scan)) return {Volume{}, err};
  if (auto err = check_data_file(path, scan)) return {Volume{}, err};
  const ShortPath sp(path);
  if (sp.path().empty())
    return {Volume{}, io_error(Code::IoError, path, "cannot open its directory")};

  std::lock_guard<std::mutex> lock(teem_mutex());
  const BiffGuard biff_guard;
  nrrdStateVerboseIO = 0;     // library code stays quiet; errors come back through biff
  NrrdPtr header(nrrdNew());  // pass 1: the header only
  IoStatePtr hio(nrrdIoStateNew());
  nrrdIoStateSet(hio.get(), nrrdIoStateSkipData, AIR_TRUE);
  if (nrrdLoad(header.get(), sp.path().c_str(), hio.get()))
    return {Volume{}, io_error(Code::BadHeader, path, biff_message(&sp))};
  const Nrrd* h = header.get();
  Vec3i dims;
  if (auto err = check_header(path, h, options, dims)) return {Volume{}, err};
  AxisGeometry axes;
  Vec3f origin;
  if (auto err = geometry(path, h, axes, origin)) return {Volume{}, err};

  const std::uintmax_t voxels = static_cast<std::uintmax_t>(dims.x()) * dims.y() * dims.z();
  const std::size_t expected = voxels * nrrdTypeSize[h->type];
  const NrrdEncoding* enc = hio->encoding;
  Payload payload;
  if (auto err = locate_payload(path, scan, hio.get(), payload)) return {Volume{}, err};
  if (auto err = check_payload_size(path, enc, payload, voxels, expected)) return {Volume{}, err};

  Volume volume(dims, axes.spacing_mm, origin, *target_type(h->type));
  const bool here =
      (enc == nrrdEncodingRaw || enc == nrrdEncodingGzip) && payload.exact && payload.single;
  if (here) {  // native types straight into the volume, the others through a conversion buffer
    std::vector<unsigned char> converted;
    unsigned char* dst = nullptr;
    switch (h->type) {
      case nrrdTypeUChar:
        dst = volume.u8().data();
        break;
      case nrrdTypeUShort:
        dst = reinterpret_cast<unsigned char*>(volume.u16().data());
        break;
      case nrrdTypeFloat:
        dst = reinterpret_cast<unsigned char*>(volume.f32().data());
        break;
      default:
        converted.resize(expected), dst = converted.data();
    }
    if (auto err = read_payload(path, payload, enc == nrrdEncodingGzip, dst, expected))
      return {Volume{}, err};
    if (hio->endian != airEndianUnknown && hio->endian != airMyEndian())
      swap_endian(dst, expected, nrrdTypeSize[h->type]);
    if (!converted.empty()) fill_volume(volume, h->type, dst, expected);
  } else if (auto err = teem_payload(path, sp, h, enc, volume, expected)) {
    return {Volume{}, err};
  }
  apply_geometry(volume, axes, origin);
  return {std::move(volume), std::nullopt};
}

std::optional<VolumeIoError> write_nrrd(const Volume& volume, const std::filesystem::path& path,
                                        Compression compression, const KeyValues& key_values) {
  int type = nrrdTypeFloat;
  void* data = nullptr;
  // Teem wraps the buffer without copying and only reads it when saving.
  switch (volume.type()) {
    case VoxelType::UInt8:
      type = nrrdTypeUChar;
      data = const_cast<std::uint8_t*>(volume.u8().data());
      break;
    case VoxelType::UInt16:
      type = nrrdTypeUShort;
      data = const_cast<std::uint16_t*>(volume.u16().data());
      break;
    case VoxelType::Float32:
      type = nrrdTypeFloat;
      data = const_cast<float*>(volume.f32().data());
      break;
  }
  const Vec3i& d = volume.dims();
  const Vec3f& s = volume.spacing_mm();
  const Vec3f& o = volume.origin_mm();

  std::lock_guard<std::mutex> lock(teem_mutex());
  const BiffGuard biff_guard;
  std::unique_ptr<Nrrd, NixDeleter> nrrd(nrrdNew());
  if (nrrdWrap_va(nrrd.get(), data, type, 3, static_cast<size_t>(d.x()), static_cast<size_t>(d.y()),
                  static_cast<size_t>(d.z())))
    return io_error(Code::IoError, path, biff_message());
  // "left-posterior-superior" is what 3D Slicer, ITK and pynrrd expect for a world space in mm.
  if (nrrdSpaceSet(nrrd.get(), nrrdSpaceLeftPosteriorSuperior))
    return io_error(Code::IoError, path, biff_message());
  const double origin[3] = {decimal(o.x()), decimal(o.y()), decimal(o.z())};
  if (nrrdSpaceOriginSet(nrrd.get(), origin)) return io_error(Code::IoError, path, biff_message());
  // Space direction of axis a = spacing times the unit direction (column a of direction()).
  double dirs[3][NRRD_SPACE_DIM_MAX] = {};
  for (int a = 0; a < 3; ++a)
    for (int c = 0; c < 3; ++c) {
      const float v = volume.direction()(c, a);
      dirs[a][c] = v == 0.0f ? 0.0 : v == 1.0f ? decimal(s[a]) : decimal(s[a]) * decimal(v);
    }
  nrrdAxisInfoSet_va(nrrd.get(), nrrdAxisInfoSpaceDirection, dirs[0], dirs[1], dirs[2]);
  nrrdAxisInfoSet_va(nrrd.get(), nrrdAxisInfoKind, nrrdKindSpace, nrrdKindSpace, nrrdKindSpace);
  nrrdAxisInfoSet_va(nrrd.get(), nrrdAxisInfoCenter, nrrdCenterCell, nrrdCenterCell,
                     nrrdCenterCell);

  for (const auto& [key, value] : key_values)
    if (nrrdKeyValueAdd(nrrd.get(), key.c_str(), value.c_str()))
      return io_error(Code::IoError, path, biff_message());
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
