#pragma once
/// @file
/// @brief The warm start's checks (segment.h, inflate_balloon_from): the previous balloon's walls
/// still there, and the start mesh (warm_interior.h) inside the new volume's target.

#include <span>
#include <string>
#include <vector>

#include "segment/internal/balloon_mesh.h"
#include "segment/internal/image_sampler.h"
#include "segment/internal/step.h"
#include "segment/internal/stop_rules.h"

namespace sonomesh::segment::internal {

/// Area-weighted unit vertex normals of `m` (zero where the faces cancel), deleted faces left out.
std::vector<Vec3f> vertex_normals(const BalloonMesh& m);

/// What check_start_safe lets pass: a share of failed samples, and where region_mm > 0, samples
/// on a grain (the level stop's: blood-pool speckle grains above the level do not stop it).
struct StartAllowance {
  float share = 0.0f;
  // A sample above the wall level is a grain, not a wall, when the mean over a 3×3×3 lattice
  // this far apart around it is below the level: a wall is a region, a grain is not. 0: none.
  float region_mm = 0.0f;
};

/// The check on the new volume: every vertex and every edge midpoint of `start` lies in the
/// step's box and below `wall_level` (the cost rule's "inside", in the cost's scale), all but
/// those `allow` lets pass. Returns why not (how many samples failed, and where the first one
/// is), empty if safe.
std::string check_start_safe(const BalloonMesh& start, const ImageSampler& sampler,
                             const CostScale& scale, float wall_level, const StepKernel& box,
                             const StartAllowance& allow = {});

/// The walls the previous balloon stopped at must still be there: a vertex of `previous` that
/// the boundary cost stopped (`stop` Boundary) needs a sample at or above `wall_level` within
/// `reach_mm` along its normal, either way, or a rise along it by half the climb from the seed's
/// level (`seed_level`, grey levels) to the wall's. Returns why not when more than 10 % of them
/// lost their wall (a withdrawn needle: its sheets would meet where it was and keep its tunnel).
std::string check_walls_kept(const Mesh& previous, std::span<const StopReason> stop,
                             const ImageSampler& sampler, const CostScale& scale, float wall_level,
                             float seed_level, float reach_mm, float vox_mm, const StepKernel& box);

/// Each vertex starts as if it had climbed from the seed's level to where it stands (as
/// reinflate's vertices do), so a start part-way up a slope does not get the climb for free.
void init_start_states(BalloonMesh& start, const ImageSampler& sampler, const CostScale& scale,
                       float seed_level);

/// The path a start vertex is taken to have come along (replay_start_states).
struct ReplayPath {
  float floor_mm = 0.0f;  // how far back its darkest level is looked for
  float cost_mm = 0.0f;   // how far back its Ψ_cost is summed (the cost's leak forgets the rest)
  float step_mm = 0.0f;
  float wall_level = 0.0f;  // a sample at or above it behind the vertex ends the path there
};

/// Each vertex of `start` gets the Ψ_cost and darkest level of a vertex that inflated along its
/// normal from `path` behind it to where it stands (after init_start_states: the larger cost,
/// the darker floor), so a start near the wall stops where a cold start's vertices stop: without
/// the speckle's share of Ψ_cost and the darkest speckle of a long path under the climb backstop,
/// the warm vertices ran on past them. Ψ_cost is capped at τ_cost.
void replay_start_states(BalloonMesh& start, const ImageSampler& sampler, const CostRule& cost,
                         const ReplayPath& path, const StepKernel& box, int threads);

}  // namespace sonomesh::segment::internal
