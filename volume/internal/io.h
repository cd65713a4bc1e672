#pragma once
/// @file
/// @brief Shared pieces of the NRRD and MetaImage readers/writers.

#include <array>
#include <cstdint>
#include <filesystem>
#include <optional>
#include <string>
#include <utility>
#include <vector>

#include "volume/volume.h"

namespace sonomesh::volume::internal {

using Code = VolumeIoError::Code;

/// "<file>: <problem>" with newlines folded so the message stays on one line.
VolumeIoError io_error(Code code, const std::filesystem::path& path, std::string problem);

/// Checks header dimensions (any integer width, may be negative or huge) before anything is
/// allocated: each positive and fitting an int, the product within options.max_voxels.
std::optional<VolumeIoError> check_dims(const std::filesystem::path& path,
                                        const std::array<long long, 3>& dims,
                                        const ReadOptions& options);

/// Turns the per-axis direction vectors of a file (row a = direction of index axis a in LPS space,
/// including the spacing for NRRD and NIfTI, unit length for MetaImage) into spacing, flips and a
/// direction. Any orthonormal set of axes is accepted: a diagonal one (axis-aligned, possibly
/// flipped) becomes flips applied to the data and an identity direction, as before directions
/// were kept; any other (oblique, permuted) is kept as `direction` with the data untouched. Zero,
/// non-finite, non-orthogonal or degenerate axes are refused (UnsupportedOrientation).
struct AxisGeometry {
  Vec3f spacing_mm;
  std::array<bool, 3> flip{};           // direction points to -axis (diagonal case only)
  Mat3f direction = Mat3f::Identity();  // column c = unit LPS direction of index axis c
};
std::optional<VolumeIoError> axis_geometry(const std::filesystem::path& path,
                                           const std::array<std::array<double, 3>, 3>& directions,
                                           AxisGeometry& out);

/// Reverses the voxel order along flipped axes and moves the origin from the file's index-0 voxel
/// to the new one, so p_mm = origin + spacing ⊙ ijk holds with positive spacing; then sets the
/// direction. `file_origin_mm` is the position of the file's first voxel.
void apply_geometry(Volume& volume, const AxisGeometry& axes, const Vec3f& file_origin_mm);

/// Reads `count` bytes at `offset` of `file` into `dst`; false if the file is shorter.
bool read_bytes(const std::filesystem::path& file, std::uintmax_t offset, void* dst,
                std::size_t count);
/// Inflates `src` (zlib or gzip stream) into exactly `dst_size` bytes.
std::optional<VolumeIoError> inflate_exact(const std::filesystem::path& path,
                                           std::vector<unsigned char>& src, unsigned char* dst,
                                           std::size_t dst_size);

/// Size of a file, or nullopt if it cannot be stat'ed.
std::optional<std::uintmax_t> data_file_size(const std::filesystem::path& path);

/// Deflate cannot compress better than ~1032:1; a compressed payload claiming more is bogus.
constexpr std::uintmax_t kMaxDeflateRatio = 1032;

/// Lower-case file extension, with ".gz" kept only as part of a compound (".raw.gz").
std::string lower_extension(const std::filesystem::path& path);

VolumeReadResult read_nrrd(const std::filesystem::path& path, const ReadOptions& options);
/// NRRD key:=value pairs written after the fields (3D Slicer's segmentation fields).
using KeyValues = std::vector<std::pair<std::string, std::string>>;
std::optional<VolumeIoError> write_nrrd(const Volume& volume, const std::filesystem::path& path,
                                        Compression compression, const KeyValues& key_values = {});
VolumeReadResult read_metaimage(const std::filesystem::path& path, const ReadOptions& options);
std::optional<VolumeIoError> write_metaimage(const Volume& volume,
                                             const std::filesystem::path& path,
                                             Compression compression);
VolumeReadResult read_nifti(const std::filesystem::path& path, const ReadOptions& options);
std::optional<VolumeIoError> write_nifti(const Volume& volume, const std::filesystem::path& path);

}  // namespace sonomesh::volume::internal
