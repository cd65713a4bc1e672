// The first pass's evolution (balloon_evolution.h). Between two remeshing passes the
// connectivity is fixed, so iterations run on flat arrays (flat_arrays.h) in parallel; A_t is
// read in parallel and marked serially in vertex order, so every self-intersection stop is the
// same however the threads were scheduled.
#include "segment/internal/balloon_evolution.h"

#include <algorithm>
#include <atomic>
#include <cmath>

namespace sonomesh::segment::internal {
namespace {

constexpr int kNoVoxel = std::numeric_limits<int>::min();
// The level stop fires with the wall's near cross 1-3 voxels ahead: its crossing lies within 4.
constexpr float kLevelSnapAheadVox = 4.0f;

// A leak (the balloon escaping through a gap) shows as more vertices than a surface of the
// volume's bounding-box area (times max_area_fraction), or of max_area_mm2 when smaller, needs at
// the target edge length.
std::size_t leak_bound(const volume::Volume& grid, const BalloonOptions& o, float vox_mm) {
  const Vec3f extent_mm = grid.max_mm() - grid.min_mm();
  const float box_area_mm2 = 2.0f * (extent_mm.x() * extent_mm.y() + extent_mm.y() * extent_mm.z() +
                                     extent_mm.z() * extent_mm.x());
  float area_mm2 = o.max_area_fraction * box_area_mm2;
  if (o.max_area_mm2 > 0.0f) area_mm2 = std::min(area_mm2, o.max_area_mm2);
  const float edge_mm = o.target_edge_vox * vox_mm;
  return static_cast<std::size_t>(area_mm2 / (0.433f * edge_mm * edge_mm) * 0.5f) + 1000;
}

}  // namespace

RemeshLimits remesh_limits(const BalloonOptions& o, float vox_mm) {
  return {0.8f * o.target_edge_vox * vox_mm, (4.0f / 3.0f) * o.target_edge_vox * vox_mm};
}

BalloonMesh start_sphere(const Vec3f& seed_mm, float radius_mm) {
  BalloonMesh bm;
  make_uv_sphere(bm, seed_mm, radius_mm, 10, 11);
  return bm;
}

BalloonEvolution::BalloonEvolution(const volume::Volume& smoothed, const ImageSampler& sampler,
                                   const BalloonOptions& options, const CostRule& cost,
                                   const WallSnap& snap, BalloonMesh start, BalloonStats& stats)
    : smoothed_(smoothed),
      sampler_(sampler),
      options_(options),
      cost_(cost),
      snap_(snap),
      kernel_(options, smoothed, smoothed.spacing_mm().minCoeff()),
      limits_(remesh_limits(options, smoothed.spacing_mm().minCoeff())),
      stall_mm_(options.stall_motion_vox * smoothed.spacing_mm().minCoeff()),
      max_vertices_(leak_bound(smoothed, options, smoothed.spacing_mm().minCoeff())),
      stats_(stats),
      workers_(options.threads),
      bm_(std::move(start)),
      marks_(smoothed) {
  begin();
}

// S^0 in the flat arrays, every moving vertex moved: normals, and its band marked in A_t.
// A start vertex that is already stopped (a warm or sealed start) must not count as moved:
// compute_normals leaves a face to its lowest moved vertex, and a stopped one never computes it,
// so an active neighbour would read that face's normal unset (run-to-run differing results).
void BalloonEvolution::begin() {
  extract(bm_, a_);
  start_vertices_ = a_.pos.size();
  all_active();
  moved_.assign(a_.pos.size(), 0);
  for (const std::uint32_t v : active_) moved_[v] = kMoved | kMarks;
  compute_normals();
  mark_front();
  swept_at_window_ = marks_.grid().marked_count();
}

void BalloonEvolution::all_active() {
  active_.clear();
  for (std::uint32_t v = 0; v < a_.pos.size(); ++v)
    if (a_.reason[v] == StopReason::Moving) active_.push_back(v);
  window_ = active_;
}

void BalloonEvolution::run(std::stop_token stop) {
  int it = 0;
  for (it = 1; it <= options_.max_iterations; ++it) {
    if (stop.stop_requested()) {
      stats_.cancelled = true;
      break;
    }
    const int now_moving = iterate();
    if (now_moving == 0) {
      all_stopped_ = true;
      break;
    }
    if (it % options_.stall_window_iterations == 0) {
      // The stall test decides first; the window still counts towards the swept-out end.
      const bool stalled = stall_test(now_moving), swept_out = swept_nothing_new();
      if (stalled) {
        stats_.stalled = true;
        break;
      }
      if (swept_out) {
        // As the stall test would call it later (a few movers in a crease), or as the limit would.
        (few_moving(now_moving) ? stats_.stalled : stats_.swept_out) = true;
        break;
      }
    }
    if (it % options_.remesh_every_iterations == 0 && needs_remesh()) {
      remesh();
      keep_before_leak(it, now_moving);
      if (a_.pos.size() > max_vertices_ || leaking(now_moving)) {
        stats_.leaked = true;
        break;
      }
      if (watch_crumple_ && crumpling()) {
        crumpled_ = true;
        break;
      }
    }
  }
  stats_.iterations = std::min(it, options_.max_iterations);
  if (crumpled_) return;  // (inflated again from its start: this balloon is not taken)
  if (!all_stopped_ && !stats_.stalled && !stats_.cancelled && !stats_.leaked)
    for (auto& r : a_.reason)
      if (r == StopReason::Moving) r = StopReason::IterationLimit;
  write_back(a_, window_, bm_);
  bm_.garbage_collection();
  if (options_.open_folds) open_folds();
  stats_.front_voxels = marks_.grid().marked_count();
  stats_.front_grid_bytes = marks_.grid().memory_bytes();
}

// One iteration: every active vertex takes its step from the previous iterate, then normals
// and A_t follow. Returns the number of vertices still moving.
int BalloonEvolution::iterate() {
  std::atomic<int> moving_count{0};
  const auto t_evolve = Clock::now();
  stats_.vertex_iterations += static_cast<std::int64_t>(active_.size());
  workers_.parallel_for(active_.size(), kHeavyGrain, [&](std::size_t b, std::size_t e) {
    const FrontGrid::Reader reader(marks_.grid());
    int local_moving = 0;
    for (std::size_t i = b; i < e; ++i) local_moving += advance_vertex(active_[i], reader);
    moving_count.fetch_add(local_moving, std::memory_order_relaxed);
  });
  workers_.parallel_for(active_.size(), kLightGrain, [&](std::size_t b, std::size_t e) {
    for (std::size_t i = b; i < e; ++i)
      if (moved_[active_[i]]) a_.pos[active_[i]] = a_.next_pos[active_[i]];
  });
  stats_.evolve_ms += ms_since(t_evolve);
  const auto t_normals = Clock::now();
  compute_normals();
  stats_.normals_ms += ms_since(t_normals);
  const auto t_mark = Clock::now();
  mark_front();
  stats_.mark_ms += ms_since(t_mark);
  for (const std::uint32_t v : active_) moved_[v] = 0;
  std::erase_if(active_, [&](std::uint32_t v) { return a_.reason[v] != StopReason::Moving; });
  return moving_count.load();
}

// The umbrella's neighbour sum and the summed edge curvature H(PQ)/|PQ| over P's ring:
// |(Q − P) × (n₁ − n₂)| / |Q − P| (Sullivan), one square root per edge.
void BalloonEvolution::ring_sums(std::uint32_t v, const Vec3f& p, Vec3f& centroid,
                                 float& curvature) const {
  centroid = Vec3f::Zero();
  curvature = 0.0f;
  for (std::uint32_t r = a_.ring_begin[v]; r < a_.ring_begin[v + 1]; ++r) {
    const Vec3f q = a_.pos[a_.ring_vertex[r]];
    centroid += q;
    const Vec3f edge = q - p;
    const float len2 = edge.squaredNorm();
    if (len2 > 0.0f)
      curvature += std::sqrt(
          edge.cross(a_.face_normal[a_.ring_face_left[r]] - a_.face_normal[a_.ring_face_right[r]])
              .squaredNorm() /
          len2);
  }
}

// The step of one vertex with the stop tests in order: curvature, the volume's edge, the other
// side of the balloon in A_t, the boundary cost. Returns whether it is still moving.
bool BalloonEvolution::advance_vertex(std::uint32_t v, const FrontGrid::Reader& reader) {
  const Vec3f p = a_.pos[v];
  moved_[v] = 0;
  const Vec3f n = a_.normal[v];
  Vec3f centroid;
  float curvature;
  ring_sums(v, p, centroid, curvature);
  const float deg = static_cast<float>(a_.ring_begin[v + 1] - a_.ring_begin[v]);
  curvature /= deg;
  if (curvature > options_.tau_curv) {
    a_.reason[v] = StopReason::Curvature;
    return false;
  }
  const Vec3f d = kernel_.step(centroid / deg - p, n);
  const Vec3f target = p + d;
  if (kernel_.outside(target)) {
    a_.reason[v] = StopReason::Boundary;  // the volume's edge bounds the object
    return false;
  }
  Vec3i target_ijk;
  const bool target_in_volume = marks_.voxel(target, target_ijk);
  if (target_in_volume &&
      FrontMarks::other_side(reader, target_ijk, n, options_.self_intersection_cos)) {
    a_.reason[v] = StopReason::SelfIntersection;  // a type-1 vertex
    return false;
  }
  bool stopped = false;
  float level_wall = 0.0f;
  const float t =
      cost_.step(sampler_, p, d, n, a_.cost[v], a_.floor_level[v], a_.path[v], stopped, level_wall);
  a_.next_pos[v] = p + t * d;
  settle(v, n, stopped, level_wall, target_ijk, target_in_volume, reader);
  if (stopped) a_.reason[v] = StopReason::Boundary;
  return !stopped;
}

// After the step: a stopped vertex snaps to the wall unless that takes it into the other side
// of the balloon (the snap must not pass the test that guards every step); the vertex marks A_t
// again if it ends in a new voxel.
void BalloonEvolution::settle(std::uint32_t v, const Vec3f& n, bool stopped, float level_wall,
                              const Vec3i& target_ijk, bool target_in_volume,
                              const FrontGrid::Reader& reader) {
  if (stopped) {
    const Vec3f snapped =
        level_wall > 0.0f ? cost_.level.snap(sampler_, a_.next_pos[v], n, level_wall,
                                             kLevelSnapAheadVox * smoothed_.spacing_mm().minCoeff())
                          : snap_.apply(sampler_, a_.next_pos[v], n);
    Vec3i snapped_ijk;
    if (!marks_.voxel(snapped, snapped_ijk) ||
        !FrontMarks::other_side(reader, snapped_ijk, n, options_.self_intersection_cos))
      a_.next_pos[v] = snapped;
  }
  moved_[v] = kMoved;
  Vec3i ijk = target_ijk;
  const bool in_volume = !stopped ? target_in_volume : marks_.voxel(a_.next_pos[v], ijk);
  const std::int64_t voxel =
      in_volume ? static_cast<std::int64_t>(smoothed_.linear_index(ijk.x(), ijk.y(), ijk.z())) : -1;
  if (voxel != a_.marked_voxel[v]) {
    moved_[v] |= kMarks;
    a_.marked_voxel[v] = voxel;
  }
}

// Face normals around the vertices that moved, then the vertex normals of equation (2) of the
// active ones. Only faces around an active vertex are ever read, so a face of stopped vertices
// may keep a stale normal. Each face is computed once, by the lowest-numbered of its vertices
// that moved, so the rings can be walked in parallel.
void BalloonEvolution::compute_normals() {
  workers_.parallel_for(active_.size(), kLightGrain, [&](std::size_t b, std::size_t e) {
    for (std::size_t i = b; i < e; ++i) {
      const std::uint32_t v = active_[i];
      if (!moved_[v]) continue;
      for (std::uint32_t r = a_.ring_begin[v]; r < a_.ring_begin[v + 1]; ++r) {
        const std::uint32_t f = a_.ring_face_left[r];
        const auto& t = a_.tri[f];
        // (v is one of t; moved_[] is 0 for every vertex that is not active.)
        if ((t[0] < v && moved_[t[0]]) || (t[1] < v && moved_[t[1]]) || (t[2] < v && moved_[t[2]]))
          continue;
        a_.face_normal[f] = unit_face_normal(a_.pos, t);
      }
    }
  });
  workers_.parallel_for(active_.size(), kLightGrain, [&](std::size_t b, std::size_t e) {
    for (std::size_t i = b; i < e; ++i) {
      const std::uint32_t v = active_[i];
      Vec3f n = Vec3f::Zero();  // the normalised sum of the unit triangle normals
      for (std::uint32_t r = a_.ring_begin[v]; r < a_.ring_begin[v + 1]; ++r)
        n += a_.face_normal[a_.ring_face_left[r]];
      const float len = n.norm();
      a_.normal[v] = len > 0.0f ? Vec3f(n / len) : Vec3f::Zero();
    }
  });
}

// Marks the surface samples (its own voxel and its edges' midpoints) of every vertex that
// entered a new voxel: the front marks in every voxel it enters, so the band it leaves is close
// to solid. Found in parallel, marked serially in vertex order.
void BalloonEvolution::mark_front() {
  pending_.resize(a_.ring_vertex.size() + a_.pos.size());
  workers_.parallel_for(active_.size(), kHeavyGrain, [&](std::size_t b, std::size_t e) {
    const FrontGrid::Reader reader(marks_.grid());
    for (std::size_t i = b; i < e; ++i) stage_samples(active_[i], reader);
  });
  for (const std::uint32_t v : active_) {
    if (!(moved_[v] & kMarks)) continue;
    const std::uint32_t slot0 = a_.ring_begin[v] + v, slot1 = a_.ring_begin[v + 1] + v + 1;
    for (std::uint32_t slot = slot0; slot < slot1; ++slot)
      if (pending_[slot].x() != kNoVoxel) marks_.grid().mark(pending_[slot], a_.normal[v]);
  }
}

// The samples of v not yet in A_t, into its slots; each voxel looked up once per vertex, and an
// edge whose other end also marks is left to that end (the lower-numbered).
void BalloonEvolution::stage_samples(std::uint32_t v, const FrontGrid::Reader& reader) {
  const std::uint32_t slot0 = a_.ring_begin[v] + v;
  std::array<Vec3i, 16> seen;
  std::size_t n_seen = 0;
  auto stage = [&](std::uint32_t slot, const Vec3f& p_mm) {
    Vec3i ijk;
    pending_[slot].x() = kNoVoxel;
    if (!marks_.voxel(p_mm, ijk)) return;
    for (std::size_t k = 0; k < n_seen; ++k)
      if (seen[k] == ijk) return;
    if (n_seen < seen.size()) seen[n_seen++] = ijk;
    if (!reader.marked(ijk)) pending_[slot] = ijk;
  };
  pending_[slot0].x() = kNoVoxel;
  if (!(moved_[v] & kMarks)) return;
  stage(slot0, a_.pos[v]);
  std::uint32_t slot = slot0 + 1;
  for (std::uint32_t r = a_.ring_begin[v]; r < a_.ring_begin[v + 1]; ++r, ++slot) {
    const std::uint32_t q = a_.ring_vertex[r];
    if (q < v && (moved_[q] & kMarks)) {  // that edge is marked from q
      pending_[slot].x() = kNoVoxel;
      continue;
    }
    stage(slot, 0.5f * (a_.pos[v] + a_.pos[q]));
  }
}

// Remeshing costs O(mesh): it runs only when an edge with a moving end is out of range.
bool BalloonEvolution::needs_remesh() const {
  const float min2 = limits_.min_edge_mm * limits_.min_edge_mm;
  const float max2 = limits_.max_edge_mm * limits_.max_edge_mm;
  for (const std::uint32_t v : active_)
    for (std::uint32_t r = a_.ring_begin[v]; r < a_.ring_begin[v + 1]; ++r) {
      const float l2 = (a_.pos[a_.ring_vertex[r]] - a_.pos[v]).squaredNorm();
      if (l2 > max2 || l2 < min2) return true;
    }
  return false;
}

// Split and collapse on the halfedge mesh, then the arrays afresh; every active vertex counts
// as moved (faces may have been renumbered).
void BalloonEvolution::remesh() {
  const auto t_remesh = Clock::now();
  write_back(a_, window_, bm_);
  const auto counts = internal::remesh(bm_, limits_);
  ++stats_.remesh_passes;
  stats_.splits += counts.splits;
  stats_.collapses += counts.collapses;
  extract(bm_, a_);
  all_active();
  moved_.assign(a_.pos.size(), 0);
  for (const std::uint32_t v : active_) moved_[v] = kMoved;
  compute_normals();
  stats_.remesh_ms += ms_since(t_remesh);
}

// Called after a remeshing pass, when bm_ holds the current balloon, once it has twice the start's
// vertices. A copy is made only when the moving vertices fell by a tenth or the mesh grew by a
// tenth since the last one, so a balloon closing in on its walls copies itself a few times, not
// at every pass.
void BalloonEvolution::keep_before_leak(int iteration, int now_moving) {
  // S^0's first passes shed vertices; a sealed start is already a balloon.
  if (!sealed_start_ && bm_.n_vertices() < 2 * start_vertices_) return;
  peak_moving_ = std::max(peak_moving_, now_moving);
  if (4 * now_moving > 3 * peak_moving_) return;
  if (before_leak_) {
    if (now_moving >= before_leak_->moving) return;
    const bool fewer = 10 * now_moving < 9 * before_leak_->moving;
    const bool grown = 10 * bm_.n_vertices() > 11 * before_leak_->mesh.vertices.size();
    if (!fewer && !grown) return;
  }
  before_leak_ = snapshot(iteration, now_moving);
}

// bm_ as it is now (after a remeshing pass or at the start, when it holds the positions).
BalloonEvolution::Snapshot BalloonEvolution::snapshot(int iteration, int moving) const {
  Snapshot out{to_plain_mesh(bm_), {}, iteration, moving};
  out.states.reserve(out.mesh.vertices.size());
  for (std::uint32_t i = 0; i < bm_.n_vertices(); ++i)
    if (!bm_.is_deleted(Vertex{i})) out.states.push_back(bm_.states()[i]);
  return out;
}

void BalloonEvolution::keep_start_before_leak() {
  sealed_start_ = true;
  peak_moving_ = static_cast<int>(active_.size());
  before_leak_ = snapshot(0, peak_moving_);
}

// Past the copy kept before a leak, a balloon whose moving vertices grew sixfold and whose mesh
// tripled is spreading through a gap: waiting for the leak bound only costs time (the tomaat
// volume's level-stop balloon took 13 s to reach it).
bool BalloonEvolution::leaking(int now_moving) const {
  return before_leak_ && now_moving > 6 * before_leak_->moving &&
         a_.pos.size() > 3 * before_leak_->mesh.vertices.size();
}

std::string BalloonEvolution::leak_message() const {
  if (!stats_.leaked) return {};
  return "the balloon leaked: " + std::to_string(a_.pos.size()) +
         " vertices, more than a closed target in this volume can need (" +
         std::to_string(max_vertices_) +
         "); the wall has a gap the balloon escaped through, or the seed is not inside a closed "
         "target";
}

void BalloonEvolution::take_result(Mesh& mesh, std::vector<StopReason>& stop) {
  if (rolled_back()) {
    mesh = std::move(before_leak_->mesh);  // (the evolution has ended)
    stop.clear();
    for (const auto& s : before_leak_->states) stop.push_back(s.reason);
    stats_.leak_rollback_iteration = before_leak_->iteration;
  } else {
    mesh = to_plain_mesh(bm_);
    stop.clear();
    stop.reserve(mesh.vertices.size());
    for (const auto& s : bm_.states()) stop.push_back(s.reason);
  }
  for (const StopReason r : stop) ++stats_.stop_counts[static_cast<std::size_t>(r)];
}

}  // namespace sonomesh::segment::internal
