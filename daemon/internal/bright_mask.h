#pragma once
/// @file
/// @brief The bright voxels a needle's shadow search starts from (shadow_gain.h), and their
/// face-connected clusters.

#include <cstdint>
#include <vector>

#include "volume/volume.h"

namespace sonomesh::daemon::internal {

/// An index box (inclusive).
struct IndexBox {
  volume::Vec3i lo = volume::Vec3i::Zero(), hi = volume::Vec3i::Zero();
};

/// The index of a voxel given as Volume::linear_index.
volume::Vec3i index_of(const volume::Vec3i& dims, std::size_t voxel);

/// Which voxels of a Float32 image are bright: over `level`, with their 7-voxel cross (the voxel
/// and its face neighbours) averaging over it too; never on the volume's faces. (The cross, not
/// the 3×3×3 cube: a biopsy needle a voxel or so thick fills too little of the cube.)
class BrightMask {
 public:
  BrightMask(const volume::Volume& image, float level);

  /// Tests the voxels of `box` (clamped to the volume) over `threads`; `ones` receives the bright
  /// ones in linear order. A voxel outside every scanned box is tested when first asked: a search
  /// that scans only where the last casters were still grows its clusters whole.
  void scan(const IndexBox& box, int threads, std::vector<std::size_t>& ones);

  /// Whether the voxel is bright (tested now if not yet; not cached, so safe across threads).
  bool bright(std::size_t voxel) const;
  /// Whether the voxel is bright and not yet taken by a cluster.
  bool untaken(std::size_t voxel) const { return mark_[voxel] == kBright; }

  /// The face-connected cluster of bright voxels holding `start` (bright and untaken), each
  /// marked taken, in breadth-first order from its first voxel in linear order (wherever it was
  /// found). (A needle's bright core is a solid tube: its faces connect it.)
  void take_cluster(std::size_t start, std::vector<std::size_t>& cluster);

 private:
  static constexpr std::uint8_t kUntested = 0, kBright = 1, kTaken = 2, kDark = 3, kReordered = 4;
  // The voxel (not on the volume's faces) and its 7-voxel cross over the level.
  bool cross_over(std::ptrdiff_t at) const;
  bool test(std::size_t voxel) const;
  // The face-connected voxels marked `from` reached from `start`, in breadth-first order, marked
  // `to`.
  void flood(std::size_t start, std::uint8_t from, std::uint8_t to,
             std::vector<std::size_t>& cluster);

  const std::vector<float>& v_;
  volume::Vec3i d_;
  std::ptrdiff_t nx_, nxy_;
  float level_;
  bool all_scanned_ = false;
  std::vector<std::uint8_t> mark_;
};

}  // namespace sonomesh::daemon::internal
