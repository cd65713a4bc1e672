// The balloon evolution of method.md §1-3 (paper §2-3).
//
// Between two remeshing passes the mesh's connectivity is fixed, so the per-iteration loop runs on
// flat arrays (positions, state, one-ring in CSR form, face normals) copied from the halfedge mesh;
// positions and state go back into it for each remeshing pass. That keeps the hot loop free of
// halfedge walks and lets it run in parallel (TBB parallel_for over vertices). The mesh is
// purpose-built (balloon_mesh.h: OpenMesh's remeshing took ~70 % of the time), with flat arrays
// of its own, so the copy is a pass over arrays.
#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>
#include <tbb/task_arena.h>

#include <Eigen/Geometry>
#include <algorithm>
#include <cassert>
#include <limits>
#include <atomic>
#include <chrono>
#include <cmath>
#include <cstdint>
#include <span>
#include <stdexcept>
#include <string>
#include <thread>
#include <vector>

#include "segment/internal/balloon_mesh.h"
#include "segment/internal/image_sampler.h"
#include "segment/segment.h"

namespace sonomesh::segment {
namespace {

using internal::BalloonMesh;
using internal::ImageSampler;
using volume::Vec3i;

// ---------------------------------------------------------------------------------------------
// The occupancy A_t (volume::FrontGrid, an OpenVDB grid) with, per voxel, the normal of the front
// that first swept it.
//
// "Already inside before P's own front got there" is decided by the direction of the front that
// marked the voxel, not by its age: where two fronts meet head-on (the two ends of the tube of a
// torus, the sheets closing behind a needle) both sides marked their voxels in the last
// iteration or two, so an age test cannot tell them from P's own front, while their normals are
// opposite. P's own front marked the voxels around P with normals close to P's.
//
// A_t grows incrementally: each iteration marks only the samples of the vertices that moved. The
// iteration reads A_t in parallel (one Reader per task) and marks it afterwards in one serial
// pass in vertex order, so the first marker of a voxel, and with it every self-intersection stop,
// is the same however the threads were scheduled.
class FrontMarks {
 public:
  explicit FrontMarks(const volume::Volume& grid)
      : grid_(grid),
        dims_(grid.dims()),
        origin_mm_(grid.origin_mm()),
        inv_spacing_(grid.spacing_mm().cwiseInverse()) {}

  // Voxel containing p (voxel centres at integer indices); false outside the volume.
  bool voxel(const Vec3f& p_mm, Vec3i& ijk) const {
    // Per axis by hand: with Eigen's cwise expressions and all() it was compiled out of line
    // (3 % of the balloon's instructions).
    const float ux = (p_mm.x() - origin_mm_.x()) * inv_spacing_.x() + 0.5f;
    const float uy = (p_mm.y() - origin_mm_.y()) * inv_spacing_.y() + 0.5f;
    const float uz = (p_mm.z() - origin_mm_.z()) * inv_spacing_.z() + 0.5f;
    if (!(ux >= 0.0f && uy >= 0.0f && uz >= 0.0f)) return false;
    // Truncation is floor here (u >= 0): nearest voxel centre without lround's libm call (3 % of
    // the balloon's time at 128³).
    ijk = Vec3i(static_cast<int>(ux), static_cast<int>(uy), static_cast<int>(uz));
    return ijk.x() < dims_.x() && ijk.y() < dims_.y() && ijk.z() < dims_.z();
  }

  // True if the voxel at p was swept by a front whose normal opposes n (cosine < cos_limit).
  static bool other_side(const volume::FrontGrid::Reader& reader, const Vec3i& ijk, const Vec3f& n,
                         float cos_limit) {
    Vec3f marked_normal;
    return reader.normal(ijk, marked_normal) && marked_normal.dot(n) < cos_limit;
  }

  volume::FrontGrid& grid() { return grid_; }
  const volume::FrontGrid& grid() const { return grid_; }

 private:
  volume::FrontGrid grid_;
  Vec3i dims_;
  Vec3f origin_mm_;
  Vec3f inv_spacing_;
};

// ---------------------------------------------------------------------------------------------
// The balloon's threads. A loop is split into tasks of at least `grain` items, and runs serially
// below two of them. The grains: 128 for the per-vertex evolution and A_t lookups (1-2 thousand
// instructions per vertex), 512 for the light loops (face normals, copies). With one grain of
// 512 for all, the iterations of a torus's or cyst's front of 256-1023 vertices, most of their
// iterations, ran on one core (128³: balloon 6-9 % slower).
struct Workers {
  tbb::task_arena arena;
  bool serial = false;
  static constexpr std::size_t kHeavy = 128, kLight = 512;

  // `requested` as BalloonOptions::threads has it: 0 = all hardware threads.
  explicit Workers(int requested) : arena(resolved(requested)), serial(resolved(requested) == 1) {}

  static int resolved(int requested) {
    return requested > 0 ? requested : std::max(1, static_cast<int>(std::thread::hardware_concurrency()));
  }

  template <typename F>
  void parallel_for(std::size_t n, std::size_t grain, F&& f) {
    if (serial || n < 2 * grain) {
      f(std::size_t{0}, n);
      return;
    }
    arena.execute([&] {
      tbb::parallel_for(tbb::blocked_range<std::size_t>(0, n, grain),
                        [&](const tbb::blocked_range<std::size_t>& r) { f(r.begin(), r.end()); });
    });
  }
};

// ---------------------------------------------------------------------------------------------
// Flat working copy of the mesh between two remeshing passes.
struct Arrays {
  std::vector<Vec3f> pos;
  std::vector<Vec3f> next_pos;
  std::vector<float> cost;
  std::vector<StopReason> reason;
  std::vector<Vec3f> anchor;
  std::vector<float> path;
  std::vector<float> floor_level;
  std::vector<std::int64_t> marked_voxel;
  std::vector<Vec3f> normal;                      // vertex normals of the last iteration
  std::vector<std::array<std::uint32_t, 3>> tri;
  std::vector<Vec3f> face_normal;
  // One-ring: for vertex v, entries ring_begin[v] .. ring_begin[v+1]-1, each an outgoing edge with
  // its far vertex and the faces on its two sides (for H(PQ) and for equation (2)). Empty, and
  // the evolution state above unset, for a vertex that had stopped when they were extracted.
  std::vector<std::uint32_t> ring_begin;
  std::vector<std::uint32_t> ring_vertex;
  std::vector<std::uint32_t> ring_face_left;
  std::vector<std::uint32_t> ring_face_right;
};

// Expects no deleted elements (remesh() collects its garbage), so mesh indices are array indices.
// Only the vertices still moving get their ring and evolution state: every per-vertex loop runs
// over those (`active`), and reads the others' positions only. Once most of the balloon rests on
// the wall, a pass costs what its moving front costs (the whole mesh's rings were 8 % of the
// balloon's instructions at 128³, run after every remeshing pass). Each ring runs clockwise from
// the vertex's outgoing halfedge, as OpenMesh's did: the sums over it, and with them the results,
// stay what they were.
void extract(const BalloonMesh& bm, Arrays& a) {
  assert(!bm.has_garbage());
  const std::size_t nv = bm.n_vertices(), nh = bm.n_halfedges(), nf = bm.n_faces();
  const auto to = bm.halfedge_vertices();
  const auto next = bm.halfedge_nexts();
  const auto face = bm.halfedge_faces();
  const auto out = bm.vertex_halfedges();
  a.pos.assign(bm.points_mm().begin(), bm.points_mm().end());
  a.next_pos.resize(nv);
  a.cost.resize(nv);
  a.reason.resize(nv);
  a.anchor.resize(nv);
  a.path.resize(nv);
  a.floor_level.resize(nv);
  a.marked_voxel.resize(nv);
  a.normal.assign(nv, Vec3f::Zero());
  a.ring_begin.resize(nv + 1);
  a.ring_vertex.resize(nh);  // room for every ring
  a.ring_face_left.resize(nh);
  a.ring_face_right.resize(nh);
  const auto states = bm.states();
  std::uint32_t r = 0;
  for (std::size_t v = 0; v < nv; ++v) {
    a.ring_begin[v] = r;
    a.reason[v] = states[v].reason;
    if (a.reason[v] != StopReason::Moving) continue;  // an empty ring
    a.cost[v] = states[v].cost;
    a.anchor[v] = states[v].anchor_mm;
    a.path[v] = states[v].path_mm;
    a.floor_level[v] = states[v].floor_level;
    a.marked_voxel[v] = states[v].marked_voxel;
    const std::uint32_t start = out[v].idx;
    std::uint32_t h = start;
    do {
      a.ring_vertex[r] = to[h].idx;
      a.ring_face_left[r] = face[h].idx;
      a.ring_face_right[r] = face[h ^ 1u].idx;
      ++r;
      h = next[h ^ 1u].idx;  // clockwise to the next outgoing halfedge
    } while (h != start);
  }
  a.ring_begin[nv] = r;  // (the ring arrays keep their size: cut and regrown, they were zeroed again)
  const auto face_h = bm.face_halfedges();
  a.tri.resize(nf);
  a.face_normal.resize(nf);
  for (std::size_t f = 0; f < nf; ++f) {
    const std::uint32_t h0 = face_h[f].idx, h1 = next[h0].idx, h2 = next[h1].idx;
    a.tri[f] = {to[h0].idx, to[h1].idx, to[h2].idx};
  }
}

// Back into the mesh for a remeshing pass: the vertices that were moving when the arrays were
// extracted, the only ones whose position or state the evolution changes.
void write_back(const Arrays& a, std::span<const std::uint32_t> window, BalloonMesh& bm) {
  const auto points = bm.points_mm();
  const auto states = bm.states();
  for (const std::uint32_t v : window) {
    points[v] = a.pos[v];
    states[v] = {
        .cost = a.cost[v],
        .reason = a.reason[v],
        .anchor_mm = a.anchor[v],
        .path_mm = a.path[v],
        .floor_level = a.floor_level[v],
        .marked_voxel = a.marked_voxel[v]};
  }
}

using Clock = std::chrono::steady_clock;

double ms_since(Clock::time_point t) {
  return std::chrono::duration<double, std::milli>(Clock::now() - t).count();
}

// The increment of Ψ_cost for a step d through a point with gradient g, before the scale's
// weight: the paper's max(0, <g, d>), or summed per grid axis (BalloonOptions::rise_per_axis).
float rise_along(const Vec3f& g, const Vec3f& d, bool per_axis) {
  if (!per_axis) return std::max(0.0f, g.dot(d));
  return std::max(0.0f, g.x() * d.x()) + std::max(0.0f, g.y() * d.y()) + std::max(0.0f, g.z() * d.z());
}

// The boundary cost's stop rule (method.md §2 and the departures documented in segment.h),
// shared by the first pass and the re-inflation.
struct CostRule {
  internal::CostScale scale;
  float tau = 0.0f;           // τ_cost
  float tau_climb = 0.0f;     // the climb backstop
  float window_mm = 0.0f;     // 0: the plain sum
  float noise_per_mm = 0.0f;  // 0: no noise allowance
  bool per_axis = false;      // BalloonOptions::rise_per_axis

  // Advances one vertex by the Euler step d from p: its Ψ_cost, darkest level and path. Returns
  // the fraction of d to take (1 unless it stops inside the step) and sets `stopped`.
  float advance(const ImageSampler& sampler, const Vec3f& p, const Vec3f& d, float& cost,
                float& floor_level, float& path_mm, bool& stopped) const {
    // Ψ_cost += max(0, <∇I, S^{n+1} − S^n>): the rise of intensity along the path, with the
    // gradient at the step's midpoint (the rise over the step to second order: taken at S^n it
    // lags on a wall's rising flank, and vertices stopped ~0.2 voxel late).
    float value;
    Vec3f grad;
    sampler.value_and_gradient(p + 0.5f * d, value, grad);
    const float step_mm = d.norm();
    const float level = scale.map(value);
    floor_level = std::min(floor_level, level);
    const float decayed = window_mm > 0.0f ? cost * std::exp(-step_mm / window_mm) : cost;  // leaky
    const float rise = rise_along(grad, d, per_axis) * scale.weight(value);
    cost = decayed + rise;
    const float travelled_mm = path_mm + step_mm;
    float threshold = tau;
    if (noise_per_mm > 0.0f)
      threshold += window_mm > 0.0f ? noise_per_mm * window_mm * (1.0f - std::exp(-travelled_mm / window_mm))
                                    : noise_per_mm * travelled_mm;
    // Where Ψ_cost crosses τ_cost inside the step, the vertex stops at the crossing (the rise
    // taken as even along the step), so where it stops does not depend on the step length.
    float t = 1.0f;
    if (cost > threshold && rise > 0.0f) t = std::clamp((threshold - decayed) / rise, 0.0f, 1.0f);
    path_mm += t * step_mm;
    stopped = cost > threshold || level - floor_level > tau_climb;
    return t;
  }
};

// The relative scale's floor: 10 % of the tissue level (segment.h, relative_cost).
internal::CostScale cost_scale(bool relative, float tissue_level) {
  internal::CostScale scale;
  if (relative) {
    scale.relative = true;
    scale.floor = std::max(1e-3f, 0.1f * tissue_level);
  }
  return scale;
}

// Where a vertex that the boundary cost stopped ends (BalloonOptions::snap_to_wall): the peak of
// the image's slope along its normal n nearest to where it stopped, within [-back, +ahead], on a
// quarter-voxel lattice refined by a parabola through the peak and its two neighbours. For a
// smoothed step edge the peak is the wall's mid level whatever speckle the vertex's Ψ_cost
// collected on the way. No peak inside the window (the slope still rising at its end, or falling
// from its start) or none steep enough: there is no wall to snap to, the vertex stays. (On a
// curved wall the blur moves the peak a little towards the centre of curvature, about σ²/2r: the
// 64³ double torus's thin tubes come out with 0.94 of the true volume, where the unsnapped second
// pass over-shot to 1.02.)
struct WallSnap {
  bool on = false;
  float back_mm = 0.0f, ahead_mm = 0.0f, step_mm = 0.0f;
  float min_relative_slope_per_mm = 0.0f;  // <∇I, n> / I, per mm
  float level_floor = 1.0f;                // I floored at this (a black target)
  Vec3f box_lo, box_hi;                    // the volume's usable box (no data beyond)

  static constexpr int kMaxSamples = 4 * 8 + 1;  // back + ahead <= 8 voxels (check_options)

  // `ahead_limit_mm` shortens the window ahead (reinflate's move bound).
  Vec3f apply(const ImageSampler& sampler, const Vec3f& p, const Vec3f& n,
              float ahead_limit_mm = std::numeric_limits<float>::max()) const {
    if (!on) return p;
    const int lo = -static_cast<int>(std::lround(back_mm / step_mm));
    const int hi = static_cast<int>(std::floor(std::min(ahead_mm, ahead_limit_mm) / step_mm + 1e-3f));
    std::array<float, kMaxSamples> slope;
    std::array<bool, kMaxSamples> steep;
    for (int k = lo; k <= hi; ++k) {
      float value;
      Vec3f grad;
      sampler.value_and_gradient(p + (static_cast<float>(k) * step_mm) * n, value, grad);
      slope[k - lo] = grad.dot(n);
      steep[k - lo] = slope[k - lo] >= min_relative_slope_per_mm * std::max(value, level_floor);
    }
    // The peak nearest to the stop: a wall's slope can be lower than a speckle blob's in the
    // tissue beyond it, and the wall Ψ_cost met is the near one.
    int best = lo;  // none
    for (int k = lo + 1; k < hi; ++k) {
      const float here = slope[k - lo];
      if (!steep[k - lo] || here < slope[k - 1 - lo] || here < slope[k + 1 - lo]) continue;
      if (best == lo || std::abs(k) < std::abs(best)) best = k;
    }
    if (best == lo) return p;
    const float before = slope[best - 1 - lo], peak = slope[best - lo], after = slope[best + 1 - lo];
    const float curvature = before - 2.0f * peak + after;  // < 0 at a strict peak
    const float offset = curvature < 0.0f ? std::clamp(0.5f * (before - after) / curvature, -0.5f, 0.5f) : 0.0f;
    const Vec3f q = p + ((static_cast<float>(best) + offset) * step_mm) * n;
    return q.cwiseMax(box_lo).cwiseMin(box_hi);
  }
};

WallSnap wall_snap(const BalloonOptions& o, float vox_mm, float tissue_level, const Vec3f& box_lo,
                   const Vec3f& box_hi) {
  WallSnap s;
  s.on = o.snap_to_wall;
  s.back_mm = o.snap_back_vox * vox_mm;
  s.ahead_mm = o.snap_ahead_vox * vox_mm;
  s.step_mm = 0.25f * vox_mm;
  s.min_relative_slope_per_mm = o.snap_min_slope / vox_mm;
  s.level_floor = cost_scale(true, tissue_level).floor;  // the relative cost's
  s.box_lo = box_lo;
  s.box_hi = box_hi;
  return s;
}

void check_gradient(const volume::Volume& smoothed, const volume::Gradient& gradient,
                    const char* who) {
  for (const volume::Volume* g : {&gradient.gx, &gradient.gy, &gradient.gz})
    if (g->dims() != smoothed.dims() || g->type() != volume::VoxelType::Float32)
      throw std::invalid_argument(std::string(who) +
                                  ": gradient must be Float32 on the volume's grid (volume::central_gradient)");
}

// The sampler reads Float32 directly: other types (an unsmoothed UInt8 volume) are converted once
// into `storage`.
const volume::Volume* as_float32(const volume::Volume& v, volume::Volume& storage) {
  if (v.type() == volume::VoxelType::Float32) return &v;
  storage = volume::Volume(v.dims(), v.spacing_mm(), v.origin_mm(), volume::VoxelType::Float32);
  storage.f32() = v.to_float();
  return &storage;
}

void check_options(const BalloonOptions& o, float voxel_mm) {
  (void)voxel_mm;
  auto fail = [](const std::string& what) { throw std::invalid_argument("BalloonOptions: " + what); };
  if (!(o.time_step > 0.0f)) fail("time_step must be > 0");
  if (!(o.inflation_vox > 0.0f)) fail("inflation_vox must be > 0");
  if (o.time_step * o.inflation_vox > 0.5f)
    fail("time_step * inflation_vox must be <= 0.5 voxel (no wall may be jumped over)");
  if (!(o.umbrella_weight >= 0.0f) || o.time_step * o.umbrella_weight > 1.0f)
    fail("time_step * umbrella_weight must be in [0, 1] (explicit Euler stability)");
  if (!(o.initial_radius_vox >= 1.0f)) fail("initial_radius_vox must be >= 1");
  if (!(o.tau_cost >= 0.0f)) fail("tau_cost must be >= 0 (0 = derive from the image)");
  if (!(o.tau_cost_fraction > 0.0f && o.tau_cost_fraction < 1.0f))
    fail("tau_cost_fraction must be in (0, 1)");
  if (!(o.climb_backstop_fraction > 0.0f && o.climb_backstop_fraction <= 1.0f))
    fail("climb_backstop_fraction must be in (0, 1]");
  if (!(o.tau_curv > 0.0f)) fail("tau_curv must be > 0");
  if (!(o.snap_back_vox >= 0.0f) || !(o.snap_ahead_vox >= 0.0f) || !(o.snap_back_vox + o.snap_ahead_vox <= 8.0f))
    fail("snap_back_vox and snap_ahead_vox must be >= 0 with a sum <= 8");
  if (!(o.snap_min_slope >= 0.0f)) fail("snap_min_slope must be >= 0");
  if (!(o.cost_window_vox >= 0.0f)) fail("cost_window_vox must be >= 0 (0 = plain sum)");
  if (!(o.target_edge_vox > 0.0f)) fail("target_edge_vox must be > 0");
  if (o.remesh_every_iterations < 1) fail("remesh_every_iterations must be >= 1");
  if (o.max_iterations < 1) fail("max_iterations must be >= 1");
  if (!(o.max_area_fraction > 0.0f)) fail("max_area_fraction must be > 0");
  if (o.stall_window_iterations < 1) fail("stall_window_iterations must be >= 1");
  if (o.threads < 0) fail("threads must be >= 0");
}

}  // namespace

int euler_characteristic(const Mesh& mesh) {
  std::vector<std::uint64_t> edges;
  edges.reserve(mesh.triangles.size() * 3);
  for (const auto& t : mesh.triangles)
    for (int k = 0; k < 3; ++k) {
      std::uint64_t a = t[k], b = t[(k + 1) % 3];
      if (a > b) std::swap(a, b);
      edges.push_back((a << 32) | b);
    }
  std::sort(edges.begin(), edges.end());
  const auto e = std::unique(edges.begin(), edges.end()) - edges.begin();
  return static_cast<int>(mesh.vertices.size()) - static_cast<int>(e) +
         static_cast<int>(mesh.triangles.size());
}

BalloonResult inflate_balloon(const volume::Volume& smoothed_in, const volume::Gradient& gradient,
                              const Vec3f& seed_mm, const BalloonOptions& options,
                              std::stop_token stop) {
  const auto t0 = Clock::now();
  if (smoothed_in.empty()) throw std::invalid_argument("inflate_balloon: empty volume");
  check_gradient(smoothed_in, gradient, "inflate_balloon");
  if (!smoothed_in.contains_mm(seed_mm))
    throw std::invalid_argument("inflate_balloon: seed (" + std::to_string(seed_mm.x()) + ", " +
                                std::to_string(seed_mm.y()) + ", " + std::to_string(seed_mm.z()) +
                                ") mm lies outside the volume");
  const float vox_mm = smoothed_in.spacing_mm().minCoeff();
  check_options(options, vox_mm);

  volume::Volume converted;
  const volume::Volume* smoothed = as_float32(smoothed_in, converted);
  const ImageSampler sampler(*smoothed, gradient);

  BalloonResult result;
  BalloonStats& stats = result.stats;

  // --- Seed region: statistics, hypoechoic check, τ_cost, S^0 radius ---
  const float ball_mm = std::max(1.5f, options.initial_radius_vox) * vox_mm;
  // The relative scale's floor needs the tissue level, which the rays estimate; the first pass
  // (plain scale) gives it, the second measures the noise rate in the scale actually used.
  internal::SeedRegion seed = internal::analyse_seed(sampler, *smoothed, seed_mm, vox_mm, ball_mm, {});
  const internal::CostScale scale = cost_scale(options.relative_cost && seed.rays_hit > 0, seed.tissue_level);
  if (scale.relative) seed = internal::analyse_seed(sampler, *smoothed, seed_mm, vox_mm, ball_mm, scale);
  stats.seed_level = seed.level;
  stats.seed_sigma = seed.sigma;
  stats.tissue_level = seed.tissue_level;
  const float contrast = seed.tissue_level - seed.level;
  const float sigma_eff = std::max(seed.sigma, 0.02f * std::abs(seed.level) + 0.5f);
  auto finish_error = [&](std::string why) {
    result.error = std::move(why);
    stats.elapsed_ms = ms_since(t0);
    return result;
  };
  // A hypoechoic target: most rays meet a clear rise to a tissue level well above the seed's.
  if (2 * seed.rays_hit < seed.rays || !(contrast > 4.0f * sigma_eff) ||
      !(seed.level < 0.8f * seed.tissue_level)) {
    return finish_error(
        "seed is not in a hypoechoic region: mean intensity " + std::to_string(seed.level) +
        " around the seed, surroundings " +
        (seed.rays_hit > 0 ? std::to_string(seed.tissue_level) : std::string("not brighter")) +
        " (" + std::to_string(seed.rays_hit) + "/" + std::to_string(seed.rays) +
        " rays reach a brighter wall)");
  }
  // τ_cost: the cost of the climb from the seed's level to tau_cost_fraction of the way up to the
  // tissue level, in grey levels, expressed in the cost's scale. A smoothed step edge lies at the
  // grey-level mid point; half the *log* rise (the geometric mean of the two levels) lies about
  // 0.4 voxel inside it, which cost thin tubes a fifth of their volume (64³ torus: 0.82).
  auto climb_to = [&](float fraction) {
    return scale.map(seed.level + fraction * contrast) - scale.map(seed.level);
  };
  const float tau_cost = options.tau_cost > 0.0f ? options.tau_cost : climb_to(options.tau_cost_fraction);
  // The climb backstop: how far the image at P has risen above the darkest level on P's path.
  // Speckle cannot raise it much (it does not accumulate), a wall raises it by the whole contrast,
  // and a shadowed wall is measured from the shadowed floor. It stops a vertex that got through a
  // wall with a low Ψ_cost (a dark speckle patch in the wall) before it runs on in the tissue,
  // where the leaky Ψ_cost of speckle alone stays below τ_cost: a leak.
  const float tau_climb = std::max(tau_cost, climb_to(options.climb_backstop_fraction));
  // Speckle raises Ψ_cost a little on every step. The cost window bounds what it adds over a long
  // path (the far side of a torus); the optional noise allowance (off by default, segment.h) adds
  // the rate measured inside the target times the path to the threshold instead.
  const CostRule cost{.scale = scale,
                      .tau = tau_cost,
                      .tau_climb = tau_climb,
                      .window_mm = options.cost_window_vox * vox_mm,
                      .noise_per_mm = options.noise_allowance ? seed.noise_rise_per_mm : 0.0f,
                      .per_axis = options.rise_per_axis};
  stats.noise_rise_per_mm = seed.noise_rise_per_mm;
  stats.tau_cost_used = tau_cost;
  stats.tau_climb_used = tau_climb;

  // S^0 radius: initial_radius_vox, but inside the rays' safe reach (the sphere must start inside
  // the object) and not below one voxel. (Growing S^0 to fill the homogeneous region around the
  // seed, which method.md §1 allows, was measured: it saves early iterations of a small mesh,
  // hardly any time, and a 102-vertex sphere refined from a large radius by splits alone has
  // slivers that the evolution folds.)
  float radius_mm = std::min(options.initial_radius_vox * vox_mm, 0.8f * seed.safe_radius_mm);
  radius_mm = std::max(radius_mm, 1.0f * vox_mm);
  stats.initial_radius_mm = radius_mm;

  BalloonMesh bm;
  internal::make_uv_sphere(bm, seed_mm, radius_mm, 10, 11);

  const float h = options.time_step;
  const float lambda = options.umbrella_weight;
  const float mu_mm = options.inflation_vox * vox_mm;
  const internal::RemeshLimits limits{0.8f * options.target_edge_vox * vox_mm,
                                      (4.0f / 3.0f) * options.target_edge_vox * vox_mm};
  // Vertices stop at the volume's edge (half a voxel inside the voxel-centre box): no data beyond.
  const Vec3f box_lo = smoothed->min_mm() + Vec3f::Constant(0.5f * vox_mm);
  const Vec3f box_hi = smoothed->max_mm() - Vec3f::Constant(0.5f * vox_mm);
  const float stall_mm = options.stall_motion_vox * vox_mm;
  // A leak (the balloon escaping through a gap into the tissue) shows as a balloon larger than
  // anything the volume can hold as a closed target: bound the vertex count by the number a
  // surface of the volume's whole bounding-box area needs at the target edge length.
  const Vec3f extent_mm = smoothed->max_mm() - smoothed->min_mm();
  const float box_area_mm2 = 2.0f * (extent_mm.x() * extent_mm.y() + extent_mm.y() * extent_mm.z() +
                                     extent_mm.z() * extent_mm.x());
  const float edge_mm = options.target_edge_vox * vox_mm;
  const std::size_t max_vertices = static_cast<std::size_t>(
      options.max_area_fraction * box_area_mm2 / (0.433f * edge_mm * edge_mm) * 0.5f) + 1000;

  Workers workers(options.threads);

  FrontMarks marks(*smoothed);
  Arrays a;
  extract(bm, a);

  // The vertices still moving (k = 1), ascending: every per-iteration loop runs over these only,
  // so a balloon whose walls have mostly settled (the far end of a torus's tube still growing)
  // costs what its moving front costs.
  std::vector<std::uint32_t> active;
  // All of them after a remeshing pass (the mesh's indices changed); in between, iterations only
  // drop the ones that stopped. `window` keeps the list as it was then: the vertices write_back
  // has to copy.
  std::vector<std::uint32_t> window;
  auto all_active = [&] {
    active.clear();
    for (std::uint32_t v = 0; v < a.pos.size(); ++v)
      if (a.reason[v] == StopReason::Moving) active.push_back(v);
    window = active;
  };
  auto collect_active = [&] {
    std::erase_if(active, [&](std::uint32_t v) { return a.reason[v] != StopReason::Moving; });
  };
  // Per vertex and iteration: kMoved if it moved, kMarks as well if it also entered another voxel
  // than the one it last marked A_t from (so it marks its samples again, below).
  constexpr std::uint8_t kMoved = 1, kMarks = 2;
  std::vector<std::uint8_t> moved(a.pos.size(), kMoved | kMarks);
  // Face normals around the vertices that moved (moved[] set), then the vertex normals of
  // equation (2) of the active vertices. After a remeshing pass, which changed faces and may have
  // renumbered them all, every active vertex counts as moved. Only faces around an active vertex
  // are ever read (its normal, the curvature of its edges), so a face of stopped vertices may
  // keep a stale normal. Going through the rings makes an iteration cost what its moving front
  // costs, not a pass over every face (a torus's last hundreds of iterations move a few hundred of
  // its ~14000 faces). Each face is computed once, by the lowest-numbered of its vertices that
  // moved, so the rings can be walked in parallel. (Collecting the faces first, deduplicated
  // through a stamp per face, was serial: 5 % of the balloon's instructions on the 128³ sphere.)
  auto face_normal = [&](std::uint32_t f) {
    const auto& t = a.tri[f];
    const Vec3f n = (a.pos[t[1]] - a.pos[t[0]]).cross(a.pos[t[2]] - a.pos[t[0]]);
    const float len = n.norm();
    a.face_normal[f] = len > 0.0f ? Vec3f(n / len) : Vec3f::Zero();
  };
  auto compute_normals = [&] {
    workers.parallel_for(active.size(), Workers::kLight, [&](std::size_t b, std::size_t e) {
      for (std::size_t i = b; i < e; ++i) {
        const std::uint32_t v = active[i];
        if (!moved[v]) continue;
        for (std::uint32_t r = a.ring_begin[v]; r < a.ring_begin[v + 1]; ++r) {
          const std::uint32_t f = a.ring_face_left[r];
          const auto& t = a.tri[f];
          // (v is one of t; moved[] is 0 for every vertex that is not active.)
          if ((t[0] < v && moved[t[0]]) || (t[1] < v && moved[t[1]]) || (t[2] < v && moved[t[2]])) continue;
          face_normal(f);
        }
      }
    });
    workers.parallel_for(active.size(), Workers::kLight, [&](std::size_t b, std::size_t e) {
      for (std::size_t i = b; i < e; ++i) {
        const std::uint32_t v = active[i];
        Vec3f n = Vec3f::Zero();  // equation (2): normalised sum of the unit triangle normals
        for (std::uint32_t r = a.ring_begin[v]; r < a.ring_begin[v + 1]; ++r)
          n += a.face_normal[a.ring_face_left[r]];
        const float len = n.norm();
        a.normal[v] = len > 0.0f ? Vec3f(n / len) : Vec3f::Zero();
      }
    });
  };

  // Marks the surface samples of every vertex that entered a new voxel: its own voxel and the
  // midpoints of its edges. Edges are at most 4/3 L long (2.33 voxels at the default L), so the
  // samples lie at most 1.17 voxels apart: one sweep can miss a voxel between two, but the front
  // marks again in every voxel it enters, and the band it leaves is close to solid (128³ sphere:
  // 137 500 voxels swept at L = 1.75 voxels, 139 700 at L = 1.5). A vertex that moved within its
  // voxel marks nothing: at 0.3 voxel per iteration that is most iterations, and every sample was
  // looked up ~13 times per voxel it marked. An edge midpoint that crossed into a new voxel while
  // both ends stayed in theirs is marked when one end crosses, at most a voxel of travel later.
  // Two phases: the samples not yet in A_t are found in parallel (slot r + v of vertex v's CSR
  // range, one per edge plus its own), then marked serially in vertex order.
  constexpr int kNoVoxel = std::numeric_limits<int>::min();
  std::vector<Vec3i> pending;
  auto mark_front = [&] {
    pending.resize(a.ring_vertex.size() + a.pos.size());
    workers.parallel_for(active.size(), Workers::kHeavy, [&](std::size_t b, std::size_t e) {
      const volume::FrontGrid::Reader reader(marks.grid());
      for (std::size_t i = b; i < e; ++i) {
        const std::uint32_t v = active[i];
        const std::uint32_t slot0 = a.ring_begin[v] + v;
        // A vertex's samples often share voxels (an edge's midpoint lies 0.5-1 voxel from it):
        // each voxel is looked up in A_t once per vertex.
        std::array<Vec3i, 16> seen;
        std::size_t n_seen = 0;
        auto stage = [&](std::uint32_t slot, const Vec3f& p_mm) {
          Vec3i ijk;
          pending[slot].x() = kNoVoxel;
          if (!marks.voxel(p_mm, ijk)) return;
          for (std::size_t k = 0; k < n_seen; ++k)
            if (seen[k] == ijk) return;
          if (n_seen < seen.size()) seen[n_seen++] = ijk;
          if (!reader.marked(ijk)) pending[slot] = ijk;
        };
        pending[slot0].x() = kNoVoxel;
        if (!(moved[v] & kMarks)) continue;
        stage(slot0, a.pos[v]);
        std::uint32_t slot = slot0 + 1;
        for (std::uint32_t r = a.ring_begin[v]; r < a.ring_begin[v + 1]; ++r, ++slot) {
          const std::uint32_t q = a.ring_vertex[r];
          if (q < v && (moved[q] & kMarks)) {  // that edge is marked from q
            pending[slot].x() = kNoVoxel;
            continue;
          }
          stage(slot, 0.5f * (a.pos[v] + a.pos[q]));
        }
      }
    });
    for (const std::uint32_t v : active) {
      if (!(moved[v] & kMarks)) continue;
      const std::uint32_t slot0 = a.ring_begin[v] + v, slot1 = a.ring_begin[v + 1] + v + 1;
      for (std::uint32_t slot = slot0; slot < slot1; ++slot)
        if (pending[slot].x() != kNoVoxel) marks.grid().mark(pending[slot], a.normal[v]);
    }
  };

  all_active();
  compute_normals();  // (every vertex starts as moved)
  mark_front();

  // Is an edge with a moving end out of [ε_min, ε_max]? Remeshing (and the re-extraction of the
  // flat arrays after it) costs O(mesh), so a pass runs only when it has something to do.
  const float min2 = limits.min_edge_mm * limits.min_edge_mm, max2 = limits.max_edge_mm * limits.max_edge_mm;
  auto needs_remesh = [&] {
    for (const std::uint32_t v : active)
      for (std::uint32_t r = a.ring_begin[v]; r < a.ring_begin[v + 1]; ++r) {
        const float l2 = (a.pos[a.ring_vertex[r]] - a.pos[v]).squaredNorm();
        if (l2 > max2 || l2 < min2) return true;
      }
    return false;
  };

  const WallSnap snap = wall_snap(options, vox_mm, seed.tissue_level, box_lo, box_hi);
  int it = 0;
  bool all_stopped = false;
  int fewest_moving = std::numeric_limits<int>::max();
  int windows_without_drop = 0;
  for (it = 1; it <= options.max_iterations; ++it) {
    if (stop.stop_requested()) {
      stats.cancelled = true;
      break;
    }
    // Normals are current for a.pos here; every update reads the previous iterate only.
    std::atomic<int> moving_count{0};
    const auto t_evolve = Clock::now();
    stats.vertex_iterations += static_cast<std::int64_t>(active.size());
    workers.parallel_for(active.size(), Workers::kHeavy, [&](std::size_t b, std::size_t e) {
      const volume::FrontGrid::Reader reader(marks.grid());
      int local_moving = 0;
      for (std::size_t i = b; i < e; ++i) {
        const std::uint32_t v = active[i];
        const Vec3f p = a.pos[v];
        moved[v] = 0;
        const std::uint32_t r0 = a.ring_begin[v], r1 = a.ring_begin[v + 1];
        const Vec3f n = a.normal[v];
        Vec3f centroid = Vec3f::Zero();
        float curvature = 0.0f;
        for (std::uint32_t r = r0; r < r1; ++r) {
          const Vec3f q = a.pos[a.ring_vertex[r]];
          centroid += q;
          // H(PQ)/|PQ| = |(Q − P) × (n₁ − n₂)| / |Q − P| (Sullivan), normalised by the edge
          // length; one square root per edge.
          const Vec3f edge = q - p;
          const float len2 = edge.squaredNorm();
          if (len2 > 0.0f)
            curvature += std::sqrt(edge.cross(a.face_normal[a.ring_face_left[r]] -
                                              a.face_normal[a.ring_face_right[r]]).squaredNorm() / len2);
        }
        const float deg = static_cast<float>(r1 - r0);
        curvature /= deg;
        if (curvature > options.tau_curv) {
          a.reason[v] = StopReason::Curvature;
          continue;
        }
        const Vec3f umbrella = centroid / deg - p;  // U(P)
        const Vec3f d = h * (lambda * umbrella + mu_mm * n);
        const Vec3f target = p + d;
        if ((target.array() < box_lo.array()).any() || (target.array() > box_hi.array()).any()) {
          a.reason[v] = StopReason::Boundary;  // the volume's edge bounds the object
          continue;
        }
        Vec3i target_ijk;
        const bool target_in_volume = marks.voxel(target, target_ijk);
        if (target_in_volume &&
            FrontMarks::other_side(reader, target_ijk, n, options.self_intersection_cos)) {
          a.reason[v] = StopReason::SelfIntersection;  // a type-1 vertex
          continue;
        }
        bool stopped = false;
        const float t = cost.advance(sampler, p, d, a.cost[v], a.floor_level[v], a.path[v], stopped);
        a.next_pos[v] = p + t * d;
        if (stopped) {
          // Snapped, unless that would take it into the other side of the balloon: the snap must
          // not carry a vertex past the self-intersection test that guards every step.
          const Vec3f snapped = snap.apply(sampler, a.next_pos[v], n);
          Vec3i snapped_ijk;
          if (!marks.voxel(snapped, snapped_ijk) ||
              !FrontMarks::other_side(reader, snapped_ijk, n, options.self_intersection_cos))
            a.next_pos[v] = snapped;
        }
        moved[v] = kMoved;
        // The voxel it ends in: the target's unless it stopped (inside the step, or snapped).
        Vec3i ijk = target_ijk;
        const bool in_volume = !stopped ? target_in_volume : marks.voxel(a.next_pos[v], ijk);
        const std::int64_t voxel =
            in_volume ? static_cast<std::int64_t>(smoothed->linear_index(ijk.x(), ijk.y(), ijk.z())) : -1;
        if (voxel != a.marked_voxel[v]) {
          moved[v] |= kMarks;
          a.marked_voxel[v] = voxel;
        }
        if (stopped) a.reason[v] = StopReason::Boundary;
        else ++local_moving;
      }
      moving_count.fetch_add(local_moving, std::memory_order_relaxed);
    });
    workers.parallel_for(active.size(), Workers::kLight, [&](std::size_t b, std::size_t e) {
      for (std::size_t i = b; i < e; ++i)
        if (moved[active[i]]) a.pos[active[i]] = a.next_pos[active[i]];
    });
    stats.evolve_ms += ms_since(t_evolve);
    const auto t_normals = Clock::now();
    compute_normals();
    stats.normals_ms += ms_since(t_normals);
    const auto t_mark = Clock::now();
    mark_front();
    stats.mark_ms += ms_since(t_mark);
    for (const std::uint32_t v : active) moved[v] = 0;
    collect_active();

    if (moving_count.load() == 0) {
      all_stopped = true;
      break;
    }
    // Stall: over a whole window no moving vertex got further than stall_motion_vox per
    // iteration from where the window started (vertices pinned where umbrella and inflation
    // balance, e.g. in the crease between a needle and the wall, never trip a stop indicator).
    if (it % options.stall_window_iterations == 0) {
      const float limit_mm = stall_mm * static_cast<float>(options.stall_window_iterations);
      bool progress = false;
      for (const std::uint32_t v : active) {
        if ((a.pos[v] - a.anchor[v]).norm() > limit_mm) progress = true;
        a.anchor[v] = a.pos[v];
      }
      // Vertices in a crease (along a needle) can also be split off and melted back by
      // remeshing every pass, so they look as if they moved; if at most 1 % of the vertices
      // still move and their number has not dropped for three windows, the evolution is over.
      const int now_moving = moving_count.load();
      // (Compared with the fewest seen: remeshing creates moving vertices, so the count can
      // oscillate without ever settling.)
      windows_without_drop = now_moving < fewest_moving ? 0 : windows_without_drop + 1;
      fewest_moving = std::min(fewest_moving, now_moving);
      const bool few = now_moving <= std::max(10, static_cast<int>(a.pos.size() / 100));
      if (!progress || (few && windows_without_drop >= 3)) {
        stats.stalled = true;
        break;
      }
    }
    if (it % options.remesh_every_iterations == 0 && needs_remesh()) {
      const auto t_remesh = Clock::now();
      write_back(a, window, bm);
      const auto counts = internal::remesh(bm, limits);
      ++stats.remesh_passes;
      stats.splits += counts.splits;
      stats.collapses += counts.collapses;
      extract(bm, a);
      all_active();
      // Also after collapses renumbered the mesh: whatever a face index held before, the faces
      // around the active vertices, the only ones read, are computed afresh. (The next iteration
      // clears moved[] again before it moves anything.)
      moved.assign(a.pos.size(), 0);
      for (const std::uint32_t v : active) moved[v] = kMoved;
      compute_normals();
      stats.remesh_ms += ms_since(t_remesh);
      if (a.pos.size() > max_vertices) {
        stats.leaked = true;
        break;
      }
    }
  }
  stats.iterations = std::min(it, options.max_iterations);
  const bool hit_limit = !all_stopped && !stats.stalled && !stats.cancelled && !stats.leaked;
  if (hit_limit)
    for (auto& r : a.reason)
      if (r == StopReason::Moving) r = StopReason::IterationLimit;

  write_back(a, window, bm);
  bm.garbage_collection();
  stats.front_voxels = marks.grid().marked_count();
  stats.front_grid_bytes = marks.grid().memory_bytes();
  if (stats.leaked) {
    return finish_error("the balloon leaked: " + std::to_string(a.pos.size()) +
                        " vertices, more than a closed target in this volume can need (" +
                        std::to_string(max_vertices) + "); the wall has a gap the balloon "
                        "escaped through, or the seed is not inside a closed target");
  }
  result.mesh = internal::to_plain_mesh(bm);
  result.stop.reserve(result.mesh.vertices.size());
  for (const auto& s : bm.states()) {
    const StopReason r = s.reason;
    result.stop.push_back(r);
    ++stats.stop_counts[static_cast<std::size_t>(r)];
  }
  result.converged = all_stopped || stats.stalled;
  stats.elapsed_ms = ms_since(t0);
  return result;
}

BalloonResult reinflate(const volume::Volume& smoothed_in, const volume::Gradient& gradient,
                        const Mesh& surface, const BalloonStats& first_pass,
                        const BalloonOptions& options, const ReinflateOptions& pass,
                        std::stop_token stop) {
  const auto t0 = Clock::now();
  if (smoothed_in.empty()) throw std::invalid_argument("reinflate: empty volume");
  check_gradient(smoothed_in, gradient, "reinflate");
  if (!(first_pass.tissue_level > first_pass.seed_level))
    throw std::invalid_argument("reinflate: first_pass holds no seed statistics (a balloon that ran)");
  if (!(pass.max_move_vox > 0.0f) || pass.max_iterations < 1)
    throw std::invalid_argument("reinflate: max_move_vox must be > 0 and max_iterations >= 1");
  const float vox_mm = smoothed_in.spacing_mm().minCoeff();
  check_options(options, vox_mm);
  volume::Volume converted;
  const volume::Volume& smoothed = *as_float32(smoothed_in, converted);
  const ImageSampler sampler(smoothed, gradient);

  // Vertex -> incident faces (CSR). The pass needs no halfedges: the umbrella's centroid and the
  // normal of equation (2) are sums over the incident faces, and the connectivity never changes.
  // (A halfedge mesh of a 128³ reconstruction took longer to build than the pass to run.)
  const std::size_t nv = surface.vertices.size(), nf = surface.triangles.size();
  std::vector<std::uint32_t> face_begin(nv + 1, 0), faces(3 * nf);
  for (const auto& t : surface.triangles)
    for (const std::uint32_t v : t) {
      if (v >= nv) throw std::invalid_argument("reinflate: triangle index out of range");
      ++face_begin[v + 1];
    }
  for (std::size_t v = 0; v < nv; ++v) face_begin[v + 1] += face_begin[v];
  {
    std::vector<std::uint32_t> fill(face_begin.begin(), face_begin.end() - 1);
    for (std::uint32_t f = 0; f < nf; ++f)
      for (const std::uint32_t v : surface.triangles[f]) faces[fill[v]++] = f;
  }
  // Closed at every vertex: in its link, the edges (b, c) opposite it in its faces (counter-
  // clockwise), every neighbour starts exactly one link edge and ends one. An open surface (a
  // border edge) or an edge with more than two faces fails this.
  std::vector<std::uint32_t> from, to;  // any valence: a closed manifold has no bound on it
  for (std::uint32_t v = 0; v < nv; ++v) {
    const std::uint32_t deg = face_begin[v + 1] - face_begin[v];
    if (deg < 3)
      throw std::invalid_argument("reinflate: the surface is not closed at vertex " + std::to_string(v) +
                                  " (fewer than 3 faces)");
    from.resize(deg);
    to.resize(deg);
    for (std::uint32_t i = 0; i < deg; ++i) {
      const auto& t = surface.triangles[faces[face_begin[v] + i]];
      const int k = t[0] == v ? 0 : t[1] == v ? 1 : 2;
      from[i] = t[(k + 1) % 3];
      to[i] = t[(k + 2) % 3];
    }
    std::sort(from.begin(), from.begin() + deg);
    std::sort(to.begin(), to.begin() + deg);
    if (!std::equal(from.begin(), from.begin() + deg, to.begin()) ||
        std::adjacent_find(from.begin(), from.begin() + deg) != from.begin() + deg)
      throw std::invalid_argument("reinflate: the surface is not closed (or not manifold) at vertex " +
                                  std::to_string(v));
  }
  std::vector<Vec3f> pos = surface.vertices, next_pos = surface.vertices;
  std::vector<float> cost_of(nv), floor_of(nv), path_of(nv, 0.0f);
  std::vector<StopReason> reason(nv);

  // The first pass's rule, seed statistics and thresholds: both passes stop at the same level.
  // Except the per-axis split of the rise (rise_per_axis): the cancellation it prevents builds up
  // along the first pass's long paths beside a shadow's edge, while this pass moves at most
  // max_move_vox from the wall, and the split's speckle would only hold it back.
  const internal::CostScale scale = cost_scale(options.relative_cost, first_pass.tissue_level);
  const CostRule cost{.scale = scale,
                      .tau = first_pass.tau_cost_used,
                      .tau_climb = first_pass.tau_climb_used,
                      .window_mm = options.cost_window_vox * vox_mm,
                      .noise_per_mm = options.noise_allowance ? first_pass.noise_rise_per_mm : 0.0f};
  const float seed_level = scale.map(first_pass.seed_level);
  const float wall_level = scale.map(first_pass.seed_level + options.tau_cost_fraction *
                                                                 (first_pass.tissue_level - first_pass.seed_level));
  // Each vertex starts as if it had climbed from the seed's level to where it stands (Ψ_cost is
  // what a path from inside has climbed), so a vertex part-way up the wall climbs only the rest.
  // A vertex already above the level where the first pass stops is at or past the wall: it stays.
  Workers workers(options.threads);
  workers.parallel_for(nv, Workers::kLight, [&](std::size_t b, std::size_t e) {
    for (std::size_t v = b; v < e; ++v) {
      const float level = scale.map(sampler.value(pos[v]));
      cost_of[v] = std::max(0.0f, level - seed_level);
      floor_of[v] = std::min(level, seed_level);
      reason[v] = level >= wall_level ? StopReason::Boundary : StopReason::Moving;
    }
  });
  std::vector<std::uint32_t> active;
  for (std::uint32_t v = 0; v < nv; ++v)
    if (reason[v] == StopReason::Moving) active.push_back(v);

  BalloonResult result;
  BalloonStats& stats = result.stats;
  stats.seed_level = first_pass.seed_level;
  stats.tissue_level = first_pass.tissue_level;
  stats.tau_cost_used = first_pass.tau_cost_used;
  stats.tau_climb_used = first_pass.tau_climb_used;
  const float h = options.time_step, lambda = options.umbrella_weight;
  const float mu_mm = options.inflation_vox * vox_mm, max_move_mm = pass.max_move_vox * vox_mm;
  const Vec3f box_lo = smoothed.min_mm() + Vec3f::Constant(0.5f * vox_mm);
  const Vec3f box_hi = smoothed.max_mm() - Vec3f::Constant(0.5f * vox_mm);
  const WallSnap snap = wall_snap(options, vox_mm, first_pass.tissue_level, box_lo, box_hi);
  // Over the vertices still moving: most of the surface is on the wall from the start. Split over
  // the threads like the first pass (the wall snap of the vertices that stop was 43 % of this
  // pass's instructions at 128³).
  auto face_normal = [&](std::uint32_t f) {
    const auto& t = surface.triangles[f];
    const Vec3f n = (pos[t[1]] - pos[t[0]]).cross(pos[t[2]] - pos[t[0]]);
    const float len = n.norm();
    return len > 0.0f ? Vec3f(n / len) : Vec3f::Zero();
  };
  int it = 0;
  for (it = 1; it <= pass.max_iterations && !active.empty(); ++it) {
    if (stop.stop_requested()) {
      stats.cancelled = true;
      break;
    }
    workers.parallel_for(active.size(), Workers::kHeavy, [&](std::size_t b, std::size_t e) {
      for (std::size_t k = b; k < e; ++k) {
        const std::uint32_t v = active[k];
        const Vec3f p = pos[v];
        Vec3f n = Vec3f::Zero(), centroid = Vec3f::Zero();
        for (std::uint32_t i = face_begin[v]; i < face_begin[v + 1]; ++i) {
          n += face_normal(faces[i]);  // equation (2)
          for (const std::uint32_t q : surface.triangles[faces[i]]) centroid += pos[q];
        }
        if (n.norm() > 0.0f) n.normalize();
        // U(P): each of the deg neighbours is in two of the faces, and P itself in all of them.
        const float deg = static_cast<float>(face_begin[v + 1] - face_begin[v]);
        const Vec3f umbrella = (centroid - deg * p) / (2.0f * deg) - p;
        const Vec3f d = h * (lambda * umbrella + mu_mm * n);
        const Vec3f target = p + d;
        if ((target.array() < box_lo.array()).any() || (target.array() > box_hi.array()).any()) {
          reason[v] = StopReason::Boundary;
          continue;
        }
        bool stopped = false;
        const float t = cost.advance(sampler, p, d, cost_of[v], floor_of[v], path_of[v], stopped);
        // (Snapped no further ahead than the move bound allows.)
        next_pos[v] = stopped ? snap.apply(sampler, p + t * d, n, std::max(0.0f, max_move_mm - path_of[v])) : p + t * d;
        if (stopped) reason[v] = StopReason::Boundary;
        else if (path_of[v] >= max_move_mm) reason[v] = StopReason::IterationLimit;  // moved its most
      }
    });
    // Every update above read the previous iterate; now they take effect.
    for (const std::uint32_t v : active) pos[v] = next_pos[v];
    std::erase_if(active, [&](std::uint32_t v) { return reason[v] != StopReason::Moving; });
  }
  stats.iterations = std::min(it, pass.max_iterations);
  for (const std::uint32_t v : active) reason[v] = StopReason::IterationLimit;
  result.converged = active.empty();
  result.mesh.vertices = std::move(pos);
  result.mesh.triangles = surface.triangles;
  for (const StopReason r : reason) ++stats.stop_counts[static_cast<std::size_t>(r)];
  result.stop = std::move(reason);
  stats.elapsed_ms = ms_since(t0);
  return result;
}

BalloonResult inflate_balloon(const volume::Volume& image, float sigma_mm, const Vec3f& seed_mm,
                              const BalloonOptions& options, std::stop_token stop) {
  if (image.empty()) throw std::invalid_argument("inflate_balloon: empty volume");
  if (!image.contains_mm(seed_mm))
    throw std::invalid_argument("inflate_balloon: seed lies outside the volume");
  const volume::Volume smoothed = volume::smooth_gaussian(image, sigma_mm);
  const volume::Gradient gradient = volume::central_gradient(smoothed);
  return inflate_balloon(smoothed, gradient, seed_mm, options, std::move(stop));
}

}  // namespace sonomesh::segment
