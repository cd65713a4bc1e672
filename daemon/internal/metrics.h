#pragma once
/// @file
/// @brief Label-volume measures shared by the pipeline (deepest interior point), the tests and the
/// accuracy report: Euclidean distance transform, Dice, boundary distances.

#include <vector>

#include "volume/volume.h"

namespace sonomesh::daemon::internal {

/// Exact squared Euclidean distance transform (Felzenszwalb & Huttenlocher 2012, separable),
/// anisotropic: distances in mm² using the volume's spacing. For every voxel, the squared distance
/// to the nearest voxel where `feature[idx]` is true; +inf if there is none. `dims` as in Volume.
std::vector<float> squared_distance_transform_mm2(const std::vector<bool>& feature,
                                                  const volume::Vec3i& dims,
                                                  const volume::Vec3f& spacing_mm);

/// Voxel centre deepest inside the UInt8 label volume (nonzero = inside): the maximum of the
/// distance to the nearest outside voxel (voxels beyond the border count as outside). Returns false
/// if the labels are empty.
bool deepest_interior_index(const volume::Volume& labels, volume::Vec3i& ijk, float& depth_mm);

/// Label volumes here are UInt8; anything else throws std::invalid_argument.
/// Dice coefficient 2|A∩B|/(|A|+|B|) of two UInt8 label volumes on the same grid (1 if both empty).
/// @throws std::invalid_argument if the grids differ.
double dice(const volume::Volume& a, const volume::Volume& b);

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
