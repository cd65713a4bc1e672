#pragma once
/// @file
/// @brief Sealing a leak (issue 15, docs/stopping.md): the balloon from before the leak, with the
/// vertices at the gap it leaked through stopped, to inflate again.

#include <optional>
#include <vector>

#include "segment/internal/balloon_evolution.h"

namespace sonomesh::segment::internal {

struct LeakSeal {
  BalloonMesh start;  // the balloon from before the leak, the neck's vertices stopped (Boundary)
  int sealed = 0;     // vertices stopped at the neck
};

/// The neck the balloon leaked through, found by comparing the balloon kept before the leak with
/// the leaked one: the leaked balloon's new surface (more than two voxels from the kept one) is
/// credited to the nearest vertex of the kept balloon that was still moving. A cluster of moving
/// vertices (connected by edges) credited with a leak's growth per vertex holds a neck: its
/// vertices credited with new surface, and the moving ones next to them, are stopped; the rest
/// of the cluster moves on (a neck is where the surface grew, a front moving on is beside it).
/// nullopt: no cluster grew like a leak (the rollback stands).
std::optional<LeakSeal> seal_leak(const BalloonEvolution::Snapshot& before,
                                  const std::vector<Vec3f>& leaked_mm, float vox_mm);

}  // namespace sonomesh::segment::internal
