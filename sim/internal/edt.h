#pragma once
/// @file
/// @brief Exact Euclidean distance transform of a label set (Felzenszwalb-Huttenlocher).

#include <vector>

#include "volume/volume.h"

namespace sonomesh::sim::internal {

/// Squared distance in mm^2 from every voxel to the nearest voxel whose label is 0 (voxels outside
/// the volume count as 0), honouring anisotropic spacing. Label-0 voxels get 0. x fastest.
std::vector<float> squared_distance_inside_mm2(const volume::Volume& labels);

}  // namespace sonomesh::sim::internal
