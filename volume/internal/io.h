#pragma once
/// @file
/// @brief Shared pieces of the NRRD and MetaImage readers/writers.

#include <array>
#include <cstdint>
#include <filesystem>
#include <optional>
#include <string>

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

/// Turns the per-axis direction vectors of a file (row a = direction of index axis a in space,
/// including the spacing for NRRD, unit length for MetaImage) into spacing and flips. Refuses
/// anything that is not diagonal (oblique or permuted axes) with UnsupportedOrientation.
struct AxisGeometry {
  Vec3f spacing_mm;
  std::array<bool, 3> flip{};  // direction points to -axis
};
std::optional<VolumeIoError> axis_geometry(const std::filesystem::path& path,
                                           const std::array<std::array<double, 3>, 3>& directions,
                                           AxisGeometry& out);

/// Reverses the voxel order along flipped axes and moves the origin from the file's index-0 voxel
/// to the new one, so p_mm = origin + spacing ⊙ ijk holds with positive spacing.
/// `file_origin_mm` is the position of the file's first voxel.
void apply_flips(Volume& volume, const std::array<bool, 3>& flip, const Vec3f& file_origin_mm);

/// Size of a file, or nullopt if it cannot be stat'ed.
std::optional<std::uintmax_t> data_file_size(const std::filesystem::path& path);

/// Deflate cannot compress better than ~1032:1; a compressed payload claiming more is bogus.
constexpr std::uintmax_t kMaxDeflateRatio = 1032;

/// Lower-case file extension, with ".gz" kept only as part of a compound (".raw.gz").
std::string lower_extension(const std::filesystem::path& path);

VolumeReadResult read_nrrd(const std::filesystem::path& path, const ReadOptions& options);
std::optional<VolumeIoError> write_nrrd(const Volume& volume, const std::filesystem::path& path,
                                        Compression compression);
VolumeReadResult read_metaimage(const std::filesystem::path& path, const ReadOptions& options);
std::optional<VolumeIoError> write_metaimage(const Volume& volume,
                                             const std::filesystem::path& path,
                                             Compression compression);

}  // namespace sonomesh::volume::internal
