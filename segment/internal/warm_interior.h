#pragma once
/// @file
/// @brief The warm start's start mesh from an eroded interior (segment.h, inflate_balloon_from):
/// the previous balloon's interior on a small grid around it, eroded by the inset, the component
/// at the seed, its surface extracted and remeshed to the balloon's edge length.

#include <string>

#include "segment/internal/balloon_mesh.h"

namespace sonomesh::segment::internal {

/// The start mesh from `previous` (the last volume's balloon: closed, manifold, genus 0,
/// outward), into `out`:
///  - its interior is rasterised on a grid of `cell_mm` over its bounding box plus a margin
///    (ray parity along one axis), and every cell its surface passes through is taken out of
///    it, so where two sheets of the balloon met (behind a needle) the interior stays apart;
///  - the interior is eroded by `inset_mm` (a Euclidean distance transform in the box);
///  - the component at `seed_mm` (the largest when the erosion took the seed's cell) is kept,
///    its cavities filled, and its surface extracted (OpenVDB volumeToMesh) and remeshed to
///    `limits`.
/// The surface must be one closed genus-0 manifold, as the balloon is: an interior that kept a
/// tunnel is eroded one cell more, twice at most. Returns why there is no start mesh (the
/// caller then starts cold), empty if `out` holds one.
std::string eroded_start_mesh(const Mesh& previous, const Vec3f& seed_mm, float inset_mm,
                              float cell_mm, const RemeshLimits& limits, BalloonMesh& out);

}  // namespace sonomesh::segment::internal
