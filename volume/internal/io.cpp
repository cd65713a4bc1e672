// Format dispatch and helpers shared by the NRRD and MetaImage code.
#include "volume/internal/io.h"

#include <zlib.h>

#include <Eigen/SVD>
#include <algorithm>
#include <cctype>
#include <climits>
#include <cmath>
#include <fstream>
#include <system_error>

namespace sonomesh::volume {
namespace internal {

VolumeIoError io_error(Code code, const std::filesystem::path& path, std::string problem) {
  for (char& c : problem)
    if (c == '\n' || c == '\r' || c == '\t') c = ' ';
  // Collapse the runs of spaces that folded multi-line (biff) messages leave behind.
  problem.erase(std::unique(problem.begin(), problem.end(),
                            [](char a, char b) { return a == ' ' && b == ' '; }),
                problem.end());
  while (!problem.empty() && problem.back() == ' ') problem.pop_back();
  return VolumeIoError{code, path.string() + ": " + problem};
}

std::optional<VolumeIoError> check_dims(const std::filesystem::path& path,
                                        const std::array<long long, 3>& dims,
                                        const ReadOptions& options) {
  const std::string text =
      std::to_string(dims[0]) + " x " + std::to_string(dims[1]) + " x " + std::to_string(dims[2]);
  for (long long d : dims)
    if (d <= 0 || d > INT_MAX)
      return io_error(Code::BadDimensions, path, "invalid dimensions " + text);
  // Overflow-safe: compare against the limit one factor at a time.
  std::size_t n = 1;
  for (long long d : dims) {
    const auto du = static_cast<std::size_t>(d);
    if (n > options.max_voxels / du)
      return io_error(Code::BadDimensions, path,
                      "dimensions " + text + " exceed the limit of " +
                          std::to_string(options.max_voxels) + " voxels");
    n *= du;
  }
  return std::nullopt;
}

namespace {
std::string axis_text(const std::array<double, 3>& d) {
  return "(" + std::to_string(d[0]) + " " + std::to_string(d[1]) + " " + std::to_string(d[2]) + ")";
}
}  // namespace

std::optional<VolumeIoError> axis_geometry(const std::filesystem::path& path,
                                           const std::array<std::array<double, 3>, 3>& directions,
                                           AxisGeometry& out) {
  Eigen::Matrix3d unit;  // column a = unit direction of axis a
  bool diagonal = true;
  for (int a = 0; a < 3; ++a) {
    const auto& d = directions[a];
    const double len = std::sqrt(d[0] * d[0] + d[1] * d[1] + d[2] * d[2]);
    if (!std::isfinite(len) || len <= 0.0)
      return io_error(Code::BadHeader, path,
                      "axis " + std::to_string(a) + " has a zero or non-finite direction/spacing");
    out.spacing_mm[a] = static_cast<float>(len);
    if (!std::isfinite(out.spacing_mm[a]) || out.spacing_mm[a] <= 0.0f)
      return io_error(Code::BadHeader, path,
                      "spacing of axis " + std::to_string(a) + " (" + std::to_string(len) +
                          ") is out of range");
    for (int c = 0; c < 3; ++c) {
      unit(c, a) = d[c] / len;
      if (c != a && std::abs(unit(c, a)) > 1e-6) diagonal = false;
    }
  }
  // Orthonormal within what 6-digit file headers carry; anything else would shear the grid.
  constexpr double kTolerance = 1e-4;
  for (int a = 0; a < 3; ++a)
    for (int b = a + 1; b < 3; ++b)
      if (std::abs(unit.col(a).dot(unit.col(b))) > kTolerance)
        return io_error(
            Code::UnsupportedOrientation, path,
            "directions of axes " + std::to_string(a) + " " + axis_text(directions[a]) + " and " +
                std::to_string(b) + " " + axis_text(directions[b]) +
                " are not orthogonal; only orthonormal direction matrices are supported");
  if (diagonal) {
    for (int a = 0; a < 3; ++a) out.flip[a] = unit(a, a) < 0.0;
    out.direction = Mat3f::Identity();
    return std::nullopt;
  }
  // The nearest rotation/reflection (polar factor), so round-off in the file does not accumulate.
  Eigen::JacobiSVD<Eigen::Matrix3d> svd(unit, Eigen::ComputeFullU | Eigen::ComputeFullV);
  out.direction = (svd.matrixU() * svd.matrixV().transpose()).cast<float>();
  out.flip = {false, false, false};
  return std::nullopt;
}

namespace {
template <typename T>
void flip_data(std::vector<T>& v, const Vec3i& dims, const std::array<bool, 3>& flip) {
  const std::size_t nx = dims.x(), ny = dims.y(), nz = dims.z();
  if (flip[0])
    for (std::size_t r = 0; r < ny * nz; ++r)
      std::reverse(v.begin() + r * nx, v.begin() + (r + 1) * nx);
  if (flip[1])
    for (std::size_t k = 0; k < nz; ++k)
      for (std::size_t j = 0; j < ny / 2; ++j)
        std::swap_ranges(v.begin() + (k * ny + j) * nx, v.begin() + (k * ny + j + 1) * nx,
                         v.begin() + (k * ny + (ny - 1 - j)) * nx);
  if (flip[2])
    for (std::size_t k = 0; k < nz / 2; ++k)
      std::swap_ranges(v.begin() + k * nx * ny, v.begin() + (k + 1) * nx * ny,
                       v.begin() + (nz - 1 - k) * nx * ny);
}
}  // namespace

void apply_geometry(Volume& volume, const AxisGeometry& axes, const Vec3f& file_origin_mm) {
  volume.set_direction(axes.direction);
  const std::array<bool, 3>& flip = axes.flip;
  Vec3f origin = file_origin_mm;
  for (int a = 0; a < 3; ++a)
    if (flip[a]) origin[a] -= volume.spacing_mm()[a] * static_cast<float>(volume.dims()[a] - 1);
  volume.set_origin_mm(origin);
  if (!flip[0] && !flip[1] && !flip[2]) return;
  switch (volume.type()) {
    case VoxelType::UInt8:
      flip_data(volume.u8(), volume.dims(), flip);
      break;
    case VoxelType::UInt16:
      flip_data(volume.u16(), volume.dims(), flip);
      break;
    case VoxelType::Float32:
      flip_data(volume.f32(), volume.dims(), flip);
      break;
  }
}

bool read_bytes(const std::filesystem::path& file, std::uintmax_t offset, void* dst,
                std::size_t count) {
  std::ifstream in(file, std::ios::binary);
  if (!in) return false;
  in.seekg(static_cast<std::streamoff>(offset));
  in.read(static_cast<char*>(dst), static_cast<std::streamsize>(count));
  return static_cast<std::size_t>(in.gcount()) == count;
}

std::optional<VolumeIoError> inflate_exact(const std::filesystem::path& path,
                                           std::vector<unsigned char>& src, unsigned char* dst,
                                           std::size_t dst_size) {
  z_stream zs{};
  if (inflateInit2(&zs, 15 + 32) != Z_OK)  // +32: accept zlib and gzip headers
    return io_error(Code::Compression, path, "cannot initialise zlib");
  struct End {
    z_stream* z;
    ~End() { inflateEnd(z); }
  } end{&zs};
  std::size_t in_done = 0, out_done = 0;
  unsigned char scratch[64];
  for (;;) {
    const std::size_t in_chunk = std::min<std::size_t>(src.size() - in_done, 1u << 30);
    zs.next_in = src.data() + in_done;
    zs.avail_in = static_cast<uInt>(in_chunk);
    const bool overflow = out_done == dst_size;  // all expected bytes produced; probe for more
    const std::size_t out_chunk =
        overflow ? sizeof scratch : std::min<std::size_t>(dst_size - out_done, 1u << 30);
    zs.next_out = overflow ? scratch : dst + out_done;
    zs.avail_out = static_cast<uInt>(out_chunk);
    const int ret = inflate(&zs, Z_NO_FLUSH);
    in_done += in_chunk - zs.avail_in;
    const std::size_t produced = out_chunk - zs.avail_out;
    if (overflow && produced > 0)
      return io_error(Code::SizeMismatch, path,
                      "compressed data holds more than the " + std::to_string(dst_size) +
                          " bytes the header announces");
    out_done += overflow ? 0 : produced;
    if (ret == Z_STREAM_END) break;
    if (ret == Z_OK) continue;
    if (ret == Z_BUF_ERROR && in_done == src.size())
      return io_error(Code::TruncatedData, path,
                      "compressed data ends early (" + std::to_string(out_done) + " of " +
                          std::to_string(dst_size) + " bytes)");
    if (ret == Z_BUF_ERROR) continue;
    return io_error(Code::Compression, path,
                    std::string("corrupt compressed data: ") + (zs.msg ? zs.msg : "zlib error"));
  }
  if (out_done != dst_size)
    return io_error(Code::TruncatedData, path,
                    "compressed data holds " + std::to_string(out_done) +
                        " bytes, the header needs " + std::to_string(dst_size));
  return std::nullopt;
}

std::optional<std::uintmax_t> data_file_size(const std::filesystem::path& path) {
  std::error_code ec;
  const auto size = std::filesystem::file_size(path, ec);
  if (ec) return std::nullopt;
  return size;
}

std::string lower_extension(const std::filesystem::path& path) {
  auto lower = [](std::string s) {
    for (char& c : s) c = static_cast<char>(std::tolower(static_cast<unsigned char>(c)));
    return s;
  };
  std::string ext = lower(path.extension().string());
  if (ext == ".gz") ext = lower(path.stem().extension().string()) + ext;
  return ext;
}

}  // namespace internal

VolumeReadResult read_volume(const std::filesystem::path& path, const ReadOptions& options) {
  using namespace internal;
  std::error_code ec;
  if (!std::filesystem::exists(path, ec))
    return {Volume{}, io_error(Code::NotFound, path, "no such file")};
  if (!std::filesystem::is_regular_file(path, ec))
    return {Volume{}, io_error(Code::NotFound, path, "not a regular file")};
  const std::string ext = lower_extension(path);
  try {
    if (ext == ".nrrd" || ext == ".nhdr") return read_nrrd(path, options);
    if (ext == ".mha" || ext == ".mhd") return read_metaimage(path, options);
    if (ext == ".nii" || ext == ".nii.gz") return read_nifti(path, options);
  } catch (const std::bad_alloc&) {
    return {Volume{}, io_error(Code::IoError, path, "out of memory while reading")};
  } catch (const std::exception& e) {  // e.g. Volume refusing geometry no check above caught
    return {Volume{}, io_error(Code::BadHeader, path, e.what())};
  }
  return {Volume{}, io_error(Code::UnknownFormat, path,
                             "unknown extension '" + ext +
                                 "' (expected .nrrd, .nhdr, .mha, .mhd, .nii or .nii.gz)")};
}

std::optional<VolumeIoError> write_volume(const Volume& volume, const std::filesystem::path& path,
                                          Compression compression) {
  using namespace internal;
  if (volume.empty()) return io_error(Code::BadDimensions, path, "cannot write an empty volume");
  const std::string ext = lower_extension(path);
  try {
    if (ext == ".nrrd" || ext == ".nhdr") return write_nrrd(volume, path, compression);
    if (ext == ".mha" || ext == ".mhd") return write_metaimage(volume, path, compression);
    if (ext == ".nii" || ext == ".nii.gz") return write_nifti(volume, path);
  } catch (const std::bad_alloc&) {
    return io_error(Code::IoError, path, "out of memory while writing");
  }
  return io_error(
      Code::UnknownFormat, path,
      "unknown extension '" + ext + "' (expected .nrrd, .nhdr, .mha, .mhd, .nii or .nii.gz)");
}

}  // namespace sonomesh::volume
