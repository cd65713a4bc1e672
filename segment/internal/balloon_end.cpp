// How the balloon's first pass ends (balloon_evolution.h): the stall tests, the end once A_t
// stops growing, the crumple test, and the folds opened in the balloon it leaves (docs/stopping.md
// item 16).
#include <algorithm>
#include <vector>

#include "segment/internal/balloon_evolution.h"
#include "segment/internal/warm_start.h"

namespace sonomesh::segment::internal {

// Stalled: over a whole window no moving vertex got further than stall_motion_vox per
// iteration, or at most 1 % of the vertices still move and their number has not dropped below
// the fewest seen for three windows (vertices in a crease are split off and melted back by
// remeshing, so they look as if they moved).
bool BalloonEvolution::stall_test(int now_moving) {
  const float limit_mm = stall_mm_ * static_cast<float>(options_.stall_window_iterations);
  bool progress = false;
  for (const std::uint32_t v : active_) {
    if ((a_.pos[v] - a_.anchor[v]).norm() > limit_mm) progress = true;
    a_.anchor[v] = a_.pos[v];
  }
  windows_without_drop_ = now_moving < fewest_moving_ ? 0 : windows_without_drop_ + 1;
  fewest_moving_ = std::min(fewest_moving_, now_moving);
  return !progress || (few_moving(now_moving) && windows_without_drop_ >= 3);
}

bool BalloonEvolution::few_moving(int now_moving) const {
  return now_moving <= std::max(10, static_cast<int>(a_.pos.size() / 100));
}

// Whether A_t has not grown over the last swept_out_windows stall windows: what still moves only
// moves in voxels already swept (a fold's vertices trading places), and nothing changes by the
// iteration limit. (One window was too short: a 64³ double torus's crawl round its ring paused.)
bool BalloonEvolution::swept_nothing_new() {
  const std::size_t swept = marks_.grid().marked_count();
  windows_unswept_ = swept == swept_at_window_ ? windows_unswept_ + 1 : 0;
  swept_at_window_ = swept;
  return options_.swept_out_windows > 0 && windows_unswept_ >= options_.swept_out_windows;
}

// Crumpled: the vertices at least doubled since an earlier remeshing pass while A_t grew by
// under 3 %. A leak sweeps new tissue as it grows; a crumple adds area only where the balloon
// has already swept (fronts that met at an angle pass the self-intersection test and trade
// places). |A_t| never falls, so the scan back ends at the first pass 3 % smaller.
bool BalloonEvolution::crumpling() {
  const PassSize now{a_.pos.size(), marks_.grid().marked_count()};
  pass_sizes_.push_back(now);
  for (auto it = pass_sizes_.rbegin() + 1;
       it != pass_sizes_.rend() && 100 * now.swept < 103 * it->swept; ++it)
    if (now.vertices >= 2 * it->vertices) return true;
  return false;
}

// A vertex the boundary cost stopped, with the other side of the balloon ahead of it and no wall,
// is a fold of the balloon: it is type 1, as if it had taken the step into what was
// swept (the opening removes it). Kept as a wall, a fold's sheets are extra layers of the surface
// in the samples, and the indicator counts each layer: its iso value, their mean, then cuts off
// the parts of the target that have one layer (docs/stopping.md item 16). A vertex still moving
// at the end in a fold is one too: it trades places with the fold's other sheet in swept voxels,
// and left to the limit it would read as a wall the balloon had not reached.
void BalloonEvolution::open_folds() {
  const std::vector<Vec3f> normal = vertex_normals(bm_);
  const FrontGrid::Reader reader(marks_.grid());
  for (std::uint32_t v = 0; v < bm_.n_vertices(); ++v) {
    VertexState& s = bm_.state(Vertex{v});
    const bool on_wall_or_moving =
        s.reason == StopReason::Boundary || s.reason == StopReason::IterationLimit;
    if (on_wall_or_moving && !normal[v].isZero() &&
        in_fold(reader, bm_.point_mm(Vertex{v}), normal[v]))
      s.reason = StopReason::SelfIntersection;
  }
}

// Whether p with normal n is in a fold: A_t holds p + k·n for k = 1, 1.5 and 2 voxels (the whole
// way, so that a thin structure outside the balloon, a needle's tunnel one voxel wide or more, is
// not seen through), and no wall lies within 3 voxels ahead to explain the stop (the image stays
// below half way from the seed's level to the tissue's: a balloon wrapped round a needle stops a
// layer or two short of it, and those layers are its tunnel's walls).
bool BalloonEvolution::in_fold(const FrontGrid::Reader& reader, const Vec3f& p,
                               const Vec3f& n) const {
  const float vox_mm = smoothed_.spacing_mm().minCoeff();
  for (const float k : {1.0f, 1.5f, 2.0f}) {
    Vec3i ijk;
    if (!marks_.voxel(p + (k * vox_mm) * n, ijk) || !reader.marked(ijk)) return false;
  }
  const float wall = 0.5f * (stats_.seed_level + stats_.tissue_level);
  for (const float k : {1.0f, 1.5f, 2.0f, 2.5f, 3.0f})
    if (!(sampler_.value(p + (k * vox_mm) * n) < wall)) return false;
  return true;
}

}  // namespace sonomesh::segment::internal
