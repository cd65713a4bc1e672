// Format dispatch and helpers shared by the NRRD and MetaImage code.
#include "volume/internal/io.h"

#include <algorithm>
#include <cctype>
#include <climits>
#include <cmath>
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
  const std::string text = std::to_string(dims[0]) + " x " + std::to_string(dims[1]) + " x " +
                           std::to_string(dims[2]);
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

std::optional<VolumeIoError> axis_geometry(const std::filesystem::path& path,
                                           const std::array<std::array<double, 3>, 3>& directions,
                                           AxisGeometry& out) {
  for (int a = 0; a < 3; ++a) {
    const auto& d = directions[a];
    const double len = std::sqrt(d[0] * d[0] + d[1] * d[1] + d[2] * d[2]);
    if (!std::isfinite(len) || len <= 0.0)
      return io_error(Code::BadHeader, path,
                      "axis " + std::to_string(a) + " has a zero or non-finite direction/spacing");
    for (int c = 0; c < 3; ++c)
      if (c != a && std::abs(d[c]) > 1e-6 * len)
        return io_error(Code::UnsupportedOrientation, path,
                        "direction of axis " + std::to_string(a) + " (" + std::to_string(d[0]) +
                            " " + std::to_string(d[1]) + " " + std::to_string(d[2]) +
                            ") is not along a coordinate axis; oblique or permuted volumes are "
                            "not supported, resample them first");
    out.spacing_mm[a] = static_cast<float>(len);
    if (!std::isfinite(out.spacing_mm[a]) || out.spacing_mm[a] <= 0.0f)
      return io_error(Code::BadHeader, path,
                      "spacing of axis " + std::to_string(a) + " (" + std::to_string(len) +
                          ") is out of range");
    out.flip[a] = d[a] < 0.0;
  }
  return std::nullopt;
}

namespace {
template <typename T>
void flip_data(std::vector<T>& v, const Vec3i& dims, const std::array<bool, 3>& flip) {
  const std::size_t nx = dims.x(), ny = dims.y(), nz = dims.z();
  if (flip[0])
    for (std::size_t r = 0; r < ny * nz; ++r) std::reverse(v.begin() + r * nx, v.begin() + (r + 1) * nx);
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

void apply_flips(Volume& volume, const std::array<bool, 3>& flip, const Vec3f& file_origin_mm) {
  Vec3f origin = file_origin_mm;
  for (int a = 0; a < 3; ++a)
    if (flip[a]) origin[a] -= volume.spacing_mm()[a] * static_cast<float>(volume.dims()[a] - 1);
  volume.set_origin_mm(origin);
  if (!flip[0] && !flip[1] && !flip[2]) return;
  switch (volume.type()) {
    case VoxelType::UInt8: flip_data(volume.u8(), volume.dims(), flip); break;
    case VoxelType::UInt16: flip_data(volume.u16(), volume.dims(), flip); break;
    case VoxelType::Float32: flip_data(volume.f32(), volume.dims(), flip); break;
  }
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
  } catch (const std::bad_alloc&) {
    return {Volume{}, io_error(Code::IoError, path, "out of memory while reading")};
  } catch (const std::exception& e) {  // e.g. Volume refusing geometry no check above caught
    return {Volume{}, io_error(Code::BadHeader, path, e.what())};
  }
  return {Volume{}, io_error(Code::UnknownFormat, path,
                             "unknown extension '" + ext + "' (expected .nrrd, .nhdr, .mha or .mhd)")};
}

std::optional<VolumeIoError> write_volume(const Volume& volume, const std::filesystem::path& path,
                                          Compression compression) {
  using namespace internal;
  if (volume.empty()) return io_error(Code::BadDimensions, path, "cannot write an empty volume");
  const std::string ext = lower_extension(path);
  try {
    if (ext == ".nrrd" || ext == ".nhdr") return write_nrrd(volume, path, compression);
    if (ext == ".mha" || ext == ".mhd") return write_metaimage(volume, path, compression);
  } catch (const std::bad_alloc&) {
    return io_error(Code::IoError, path, "out of memory while writing");
  }
  return io_error(Code::UnknownFormat, path,
                  "unknown extension '" + ext + "' (expected .nrrd, .nhdr, .mha or .mhd)");
}

}  // namespace sonomesh::volume
