#pragma once
/// @file
/// @brief Bright structure inside a surface (issue 15, 17): a needle through a cyst that the
/// surface passed over, or that came in since the surface was tracked.

#include <functional>
#include <optional>
#include <vector>

#include "daemon/pipeline.h"
#include "mesh/mesh.h"

namespace sonomesh::daemon::internal {

/// Whether the centre of voxel (i, j, k) of the smoothed volume lies inside the surface.
using InsideTest = std::function<bool(const Vec3i&)>;

/// The inside of a voxel-grid box (index space, inclusive) and the level that divides the
/// target's inside from its walls: half way from the seed region's level to the tissue's.
struct InsideRegion {
  Vec3i lo = Vec3i::Zero(), hi = Vec3i::Zero();
  InsideTest inside;
  float mid_level = 0.0f;
};

/// The largest 26-connected set of voxels inside brighter than the mid level in `smoothed` (a
/// dark target's working image), when it holds at least half of them all: one structure (a
/// needle), not the speckle of a dark inside; or whatever it holds, when a needle cast a shadow
/// in this volume and the surface has no tunnel (`needle_seen`): a short stretch of needle amid
/// a contrast-0.5 blood pool's bright grains holds a third of them. `deep_vox` counts those
/// of its voxels whose neighbours 2 voxels away along each axis are inside too.
struct BrightStructure {
  std::vector<Vec3i> voxels;
  long deep_vox = 0;
  Vec3i extent_vox = Vec3i::Zero();  // of its box
};
BrightStructure bright_structure(const volume::Volume& smoothed, const InsideRegion& region,
                                 bool needle_seen = false);

/// Of the same 26-connected sets, the one with the most deep voxels, however many others there
/// are: a needle pushed on from a dent, beside the thin bright shell inside a tracked surface
/// that sits on the wall.
BrightStructure deepest_bright_structure(const volume::Volume& smoothed,
                                         const InsideRegion& region);

/// Whether the structure is more than the odd bright grain inside: over 40 deep voxels.
bool solid_inside(const BrightStructure& structure);

/// Of the structure's deep voxels, those along one line: the most that lie within 3 voxels of
/// one line through two of them, and along that line the longest stretch of deep voxels within
/// 1.5 voxels of it without a gap of more than two voxels, in mm. A needle's deep voxels fill a
/// line along its length; a web of blood-pool speckle through the whole inside has few on any,
/// in stretches a few grains long. 200 lines drawn with a fixed seed; of a structure with more
/// than 4 096 deep voxels, a sample of that many is counted and the count scaled up.
struct DeepLine {
  long voxels = 0;
  float length_mm = 0.0f;
};
DeepLine deep_on_a_line(const volume::Volume& smoothed, const InsideRegion& region,
                        const BrightStructure& structure);

/// Whether the surface passed over the structure (issue 15): solid_inside, at least a quarter
/// of its voxels deep (not a shell along the surface's inside), and as long as half the
/// region's box (across the target, not a cluster of bright grains).
bool passed_over(const BrightStructure& structure, const InsideRegion& region);

/// Oriented samples on the structure's walls: at every face between one of its voxels and a dark
/// voxel inside, where the image crosses the mid level, facing up its gradient (out of the
/// target, into the structure), with the face's area.
segment::PointCloud bright_walls(const volume::Volume& smoothed, const InsideRegion& region,
                                 const BrightStructure& structure);

/// The region inside `labels` (UInt8, inside = 1, on the smoothed volume's grid), within the
/// surface's box.
InsideRegion inside_labels(const volume::Volume& labels, const mesh::Box& box,
                           const segment::BalloonStats& levels);

/// The region inside χ > iso (on its own grid), within the surface's box.
InsideRegion inside_indicator(const volume::Volume& smoothed, const volume::Volume& indicator,
                              float iso, const mesh::Box& box, const segment::BalloonStats& levels);

/// Where the surface inside `region` passed over a bright structure (bright_structure with
/// `needle_seen`, passed_over), the surface made again from `samples` with the structure's walls
/// (bright_walls) added to them; nullopt where it passed over none.
std::optional<reconstruct::SurfaceResult> with_bright_walls(
    const volume::Volume& smoothed, const InsideRegion& region, mesh::PointCloud samples,
    const Vec3f& seed_mm, const reconstruct::PoissonOptions& poisson, bool needle_seen);
/// Where the reconstructed `surface` (from `samples`) passed over a bright structure, reconstructs
/// it again with the bright structure's walls added to the samples, which opens a needle the
/// balloon wrapped into the tunnel it is. Keeps the new surface when it encloses the seed. Returns
/// whether it did. `needle_seen` as bright_structure.
bool open_bright_inside(const volume::Volume& smoothed, const segment::PointCloud& samples,
                        const Vec3f& seed_mm, const reconstruct::PoissonOptions& poisson,
                        const segment::BalloonStats& levels, bool needle_seen,
                        reconstruct::SurfaceResult& surface);

}  // namespace sonomesh::daemon::internal
