#pragma once
/// @file
/// @brief One volume as a probe delivered it: the value type every source produces.

#include <array>
#include <chrono>
#include <cstdint>
#include <memory>
#include <vector>

namespace sonomesh::acquire {

/// Voxel types a probe can deliver; the values are the probe stream protocol's codes.
enum class ProbeVoxelType : std::uint8_t { UInt8 = 1, UInt16 = 2 };

/// Bytes per voxel of a probe voxel type.
constexpr int bytes_per_voxel(ProbeVoxelType type) {
  return type == ProbeVoxelType::UInt16 ? 2 : 1;
}

/// A volume an application decoded into its own type (sonomeshd: a volume::Volume read from a
/// file), carried through a source in place of voxel bytes.
class DecodedPayload {
 public:
  virtual ~DecodedPayload() = default;
  /// The voxels as the probe stream carries them (little endian); empty if the voxel type is
  /// not a probe type.
  virtual std::vector<std::uint8_t> probe_voxels() const = 0;
};

struct RawVolume {
  std::uint64_t sequence = 0;      // +1 per volume at the probe; a gap means volumes were lost
  std::uint64_t timestamp_ns = 0;  // probe clock
  std::array<int, 3> dims{};       // nx, ny, nz; x fastest in memory
  ProbeVoxelType type = ProbeVoxelType::UInt8;
  std::array<float, 3> spacing_mm{1.0f, 1.0f, 1.0f};
  std::array<float, 3> origin_mm{0.0f, 0.0f, 0.0f};
  /// Orientation of the grid in the world (LPS) frame: column-major 3x3, column c is the unit
  /// direction of index axis c. world_mm = origin_mm + direction * (spacing_mm ⊙ ijk).
  std::array<float, 9> direction{1.0f, 0.0f, 0.0f, 0.0f, 1.0f, 0.0f, 0.0f, 0.0f, 1.0f};
  std::vector<std::uint8_t> voxels;  // nx*ny*nz*bytes_per_voxel(type), little endian
  /// Set instead of `voxels` by a reader that decoded the volume itself (then voxels is empty and
  /// `type` is meaningful only if probe_voxels() is not empty).
  std::shared_ptr<const DecodedPayload> decoded;
  std::chrono::steady_clock::time_point received{};  // host clock, when the last byte arrived
};

}  // namespace sonomesh::acquire
