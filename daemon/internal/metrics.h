#pragma once
/// @file
/// @brief Measures shared by the pipeline (deepest interior point), the tests and the accuracy
/// report: Euclidean distance transform, Dice, boundary distances.

#include <optional>
#include <vector>

#include "volume/volume.h"

namespace sonomesh::daemon::internal {

/// Exact squared Euclidean distance transform (Felzenszwalb & Huttenlocher 2012, separable),
/// anisotropic: distances in mm² using the volume's spacing. For every voxel, the squared distance
/// to the nearest voxel where `feature[idx]` is true; +inf if there is none. `dims` as in Volume.
std::vector<float> squared_distance_transform_mm2(const std::vector<bool>& feature,
                                                  const volume::Vec3i& dims,
                                                  const volume::Vec3f& spacing_mm);

/// Where seed tracking restarts: the point deepest inside the region `field > iso` of a Float32
/// field (χ on the reconstruction grid), searched within the box [lo_mm, hi_mm] (the surface's
/// bounds) on the field's cells subsampled to about `step_mm` (χ's cell may be finer than the
/// input's voxel, which is resolution enough for a seed). Only the part of the region 6-connected
/// to the cell at (or next to) `seed_mm` counts, when there is one: the surface around the seed,
/// not another blob in its box. Depth is the distance to the nearest lattice point outside (points
/// beyond the box count as outside). Nothing if the region is empty in the box.
/// @throws std::invalid_argument if the field is not Float32.
struct DeepestPoint {
  volume::Vec3f position_mm = volume::Vec3f::Zero();
  float depth_mm = 0.0f;
};
std::optional<DeepestPoint> deepest_inside(const volume::Volume& field, float iso,
                                           const volume::Vec3f& lo_mm, const volume::Vec3f& hi_mm,
                                           const volume::Vec3f& seed_mm, float step_mm);

/// Label volumes here are UInt8; anything else throws std::invalid_argument.
/// Dice coefficient 2|A∩B|/(|A|+|B|) of two UInt8 label volumes on the same grid (1 if both empty).
/// @throws std::invalid_argument if the grids differ.
double dice(const volume::Volume& a, const volume::Volume& b);

/// Radius (mm) of the ball with the volume of the inside of `labels` (a target's size, for seeds
/// placed a share of it from its centre).
double equivalent_radius_mm(const volume::Volume& labels);

/// Boundary distances between two label volumes, in voxels (index units, spacing ignored so the
/// numbers read as "voxels" on any grid). The boundary of a label set is its inside voxels with a
/// 6-neighbour outside (or on the volume border). Distances from every boundary voxel of A to the
/// nearest boundary voxel of B and vice versa are pooled: `mean_vox` is their mean (the symmetric
/// mean surface distance), `hd95_vox` their 95th percentile, `max_vox` the Hausdorff distance.
struct SurfaceDistances {
  double mean_vox = 0.0;
  double hd95_vox = 0.0;
  double max_vox = 0.0;
  bool valid = false;  // false if either boundary is empty
};
/// @throws std::invalid_argument if the grids differ.
SurfaceDistances surface_distances(const volume::Volume& a, const volume::Volume& b);

}  // namespace sonomesh::daemon::internal
