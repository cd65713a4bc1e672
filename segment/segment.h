#pragma once
/// @file
/// @brief Step 1 of the two-step method: the balloon active contour (method.md §1-3).
///
/// A small triangulated sphere at the seed inflates by explicit Euler steps
///   S^{n+1} = S^n + h·k^n·(λ·U(S^n) + μ·n^n)
/// (umbrella operator U, Kobbelt et al. 1998; vertex normal of equation (2)); every vertex stops
/// for good (k = 0) on the boundary cost, the edge curvature, a threatened self-intersection, the
/// volume's edge, or the iteration limit, and records why. The mesh is remeshed every few
/// iterations (split > 4/3 L, collapse < 4/5 L; Botsch and Kobbelt 2004) and stays closed,
/// manifold, genus 0 and outward oriented. Its type-1 (self-intersection) vertices are what the
/// reconstruction cuts out.
///
/// Units: "vox" is the volume's smallest voxel spacing (so steps stay below a voxel on every
/// axis of an anisotropic grid); positions are in mm; costs in grey levels of the smoothed image.

#include <array>
#include <cmath>
#include <cstddef>
#include <cstdint>
#include <optional>
#include <span>
#include <stop_token>
#include <string>
#include <vector>

#include "segment/mesh.h"
#include "volume/volume.h"

namespace sonomesh::segment {

/// Options of both passes. Departures from the paper are marked; docs/tuning.md has the
/// measurements behind the defaults.
struct BalloonOptions {
  // --- Evolution (explicit Euler) ---
  float time_step = 1.0f;           // h, per iteration (dimensionless time)
  float inflation_vox = 0.3f;       // μ, vox per unit time; h·μ <= 0.5 vox so no wall is jumped
  float umbrella_weight = 0.2f;     // λ, per unit time; h·λ in [0, 1] for stability
  float initial_radius_vox = 2.0f;  // S^0 radius; shrunk (down to 1 vox) to stay inside the target

  // --- Stop indicators ---
  // Departure: Ψ_cost sums the rise of log I (each rise over its starting level, floored at 10 %
  // of the tissue level), because attenuation and shadows are multiplicative. false: grey levels.
  bool relative_cost = true;
  // τ_cost in the cost's scale; 0 = derive it: the climb from the seed level to
  // tau_cost_fraction of the way to the tissue level (0.5: a smoothed step edge's mid level).
  float tau_cost = 0.0f;
  float tau_cost_fraction = 0.5f;
  // Also stop once the image has risen above the darkest level on the path by the climb to this
  // fraction, so a wall whose rise Ψ_cost under-counted still stops the vertex within it.
  float climb_backstop_fraction = 0.6f;
  // Departure: Ψ_cost leaks, exp(−|step|/W) per step, so speckle over a long path decays while a
  // wall's rise is kept. 0 = the paper's plain sum.
  float cost_window_vox = 10.0f;
  // Departure: the rise is summed per grid axis, so a shadow's fall along one axis does not
  // cancel the wall's rise along another. false: the paper's dot product.
  bool rise_per_axis = true;
  // Raise τ_cost by the speckle rate ρ measured inside the target times the path (off: vertices
  // past a wall ran on in the tissue).
  bool noise_allowance = false;
  // Departure: a vertex the boundary cost stops ends on the wall itself, the peak of the slope
  // <∇I, n> nearest to the stop within [−snap_back_vox, +snap_ahead_vox], because Ψ_cost only
  // says a wall is near. No steep enough peak: the vertex stays.
  bool snap_to_wall = true;
  float snap_back_vox = 1.0f;    // behind the stop (over-shot vertices)...
  float snap_ahead_vox = 1.5f;   // ...and ahead (speckle stops early more often); sum <= 8
  float snap_min_slope = 0.25f;  // least relative slope <∇I, n>/I per voxel (speckle stays below)
  // Departure (issue 15): a vertex the boundary cost would stop moves on while the image ahead of
  // it still looks like the inside: the mean over a cross of samples 1-3 voxels ahead along its
  // normal below the mean as far behind, raised by region_fraction of the tissue/target ratio
  // (both means carry the same attenuation and shadow). A speckle grain is one bump of Ψ_cost; it
  // is not a brighter region. 0 = off (the paper's rule alone): the default, see docs/stopping.md.
  float region_fraction = 0.0f;
  // Departure (issue 15): the level stop. A vertex stops where the image ahead of it is a
  // brighter region, not one bright grain: the means over crosses of samples 1-3 and 4-6 voxels
  // ahead both above the wall level, the target's level plus level_stop_fraction of the way to
  // the tissue's (or, where the mean behind is darker, that ratio over it); it then moves to the
  // level's crossing. Speckle raises one grain at a time, a wall the region beyond it. With it
  // on, Ψ_cost's stop stands only before a thin bright line or sheet (a needle) and in a
  // shadow, and a vertex with the wall on both sides across its normal (a gap, a needle's
  // shadow sheet) stops. 0 = off, the default (docs/stopping.md has why).
  float level_stop_fraction = 0.0f;
  float tau_curv = 1.2f;  // τ_curv: mean H(PQ)/|PQ| over P's edges (0 flat, 2 folded)
  // A marked voxel is "the other side" below this cosine between its front's normal and P's.
  float self_intersection_cos = -0.5f;
  // Departure: a crumpled balloon (its vertices doubled while A_t grew by under 3 %: fronts
  // meeting at an angle pass the test above and trade places) inflates once more from its start
  // with this stricter cosine. Off at or below self_intersection_cos (−1), and at a low contrast
  // (low_contrast; docs/stopping.md item 18).
  float crumple_self_intersection_cos = 0.0f;

  // --- Remeshing ---
  float target_edge_vox = 1.75f;  // L: split > 4/3 L, collapse < 4/5 L
  int remesh_every_iterations = 5;

  // --- Termination ---
  int max_iterations = 2000;  // remaining moving vertices then get IterationLimit
  // Leak bound: more vertices than a surface of this fraction of the volume's bounding-box area
  // needs means the balloon escaped through a gap; it ends with `error` set.
  float max_area_fraction = 1.0f;
  // The same bound as an area (mm²), when it is smaller: a pass that starts from a balloon found
  // on a coarser grid may not outgrow it by much (daemon/internal/coarse_start.h). 0: none.
  float max_area_mm2 = 0.0f;
  // A leak that rolled back is sealed and the balloon inflated again, this often at most (a
  // wall's dropout is one gap, seldom more); 0: a leak ends the balloon, rolled back.
  int max_leak_seals = 6;
  int stall_window_iterations = 20;  // stop when no moving vertex got further than
  float stall_motion_vox = 0.02f;    // stall_motion_vox per iteration over this window
  // End when A_t has not grown over this many stall windows, the movers as at the iteration
  // limit, or stalled when few (BalloonStats::swept_out); 0: run to the limit.
  int swept_out_windows = 3;
  // A vertex the cost stopped with the balloon's swept inside ahead of it is a fold, type 1
  // (docs/stopping.md item 16); false keeps it as a wall.
  bool open_folds = true;

  int threads = 0;  // 0 = all hardware threads, 1 = serial
};

/// The first option out of range, as one line naming it ("tau_curv must be > 0"), or empty when
/// the balloon runs with these options. inflate_balloon and reinflate refuse the same options.
std::string validate(const BalloonOptions& options);

struct BalloonStats {
  int iterations = 0;
  std::array<int, 5> stop_counts{};  // vertices per StopReason (indexed by its value)
  float tau_cost_used = 0.0f;        // in the cost's scale (grey levels if !relative_cost)
  float tau_climb_used = 0.0f;       // the climb backstop's threshold, same scale
  float seed_level = 0.0f;           // mean smoothed intensity around the seed
  float seed_sigma = 0.0f;           // its standard deviation
  float tissue_level = 0.0f;         // estimated surrounding tissue level (ray sampling)
  float noise_rise_per_mm = 0.0f;    // ρ, grey levels per mm
  float initial_radius_mm = 0.0f;    // the sphere's (0 for a warm start)
  bool warm_start = false;           // started from a given mesh (inflate_balloon_from)
  double start_mesh_ms = 0.0;        // the warm start's walls check, start mesh and its check
  int remesh_passes = 0;
  int splits = 0;
  int collapses = 0;
  double elapsed_ms = 0.0;
  // Where elapsed_ms went, summed over the iterations (for benchmarks): the Euler step with its
  // stop tests, the normals, marking A_t, and remeshing with the flat arrays' re-extraction.
  double evolve_ms = 0.0;
  double normals_ms = 0.0;
  double mark_ms = 0.0;
  double remesh_ms = 0.0;
  std::int64_t vertex_iterations = 0;  // moving vertices summed over the iterations
  bool stalled = false;                // ended because nothing moved any more
  bool swept_out = false;              // ended early, A_t not growing (swept_out_windows)
  bool cancelled = false;              // ended because the stop_token was triggered
  bool leaked = false;                 // ended at the leak bound (max_area_fraction)
  // Leaked, and the balloon is the one from this iteration, before the leak began (0: none kept,
  // error set and no mesh).
  int leak_rollback_iteration = 0;
  // Leaks sealed: the balloon from before the leak inflated again with the vertices at the gap
  // it leaked through stopped there, as a reader closes a wall's dropout (docs/stopping.md).
  int leak_seals = 0;
  int sealed_vertices = 0;  // summed over the seals
  // The balloon crumpled and inflated again from its start with the stricter self-intersection
  // test (BalloonOptions::crumple_self_intersection_cos); at most once.
  int crumple_restarts = 0;
  std::size_t front_voxels = 0;      // voxels in A_t (swept by the front) at the end
  std::size_t front_grid_bytes = 0;  // memory of A_t's sparse grid
};

/// `options` with the stricter self-intersection test a crumpled balloon inflates again with
/// (crumple_self_intersection_cos, where it is the stricter): for a stream whose balloon crumpled.
BalloonOptions after_crumple(const BalloonOptions& options);

/// Whether the seed region shows a low contrast: its level at 60 % of the tissue level or more
/// (under 0.4 of contrast, on an image whose zero is no echo). There a wall half the contrast
/// high is within the speckle's and the clutter's reach: the stricter self-intersection test
/// after a crumple stops fronts on the speckle, and a wall test cannot tell the target's wall
/// (docs/stopping.md items 4 and 18).
bool low_contrast(const BalloonStats& stats);

struct BalloonResult {
  Mesh mesh;                     // closed, manifold, genus 0, outward oriented (mm)
  std::vector<StopReason> stop;  // per vertex of mesh
  BalloonStats stats;
  bool converged = false;  // every vertex stopped, or the evolution stalled
  std::string error;       // non-empty: why there is no balloon (mesh empty then)
  // inflate_balloon_from only: the start mesh was not safe on this volume (error says why); the
  // caller cold-starts with inflate_balloon.
  bool start_unsafe = false;
};

/// Inflates the balloon from `seed_mm` in a volume the caller has already smoothed (method.md
/// §0). The image's gradient is the central-difference one of volume::central_gradient, taken
/// where the balloon samples it (no gradient volumes: 12 bytes per voxel the balloon never reads
/// away from its path).
/// A seed that is not in a hypoechoic region (brighter than or as bright as its surroundings,
/// e.g. on the needle or in tissue) gives a result with `error` set and an empty mesh. A balloon
/// that leaks out of its target is first sealed: the balloon from before the leak inflates again
/// with its vertices at the gap stopped (`stats.leak_seals`, a few times at most; a caller must
/// flag the result, the surface at a seal is on no wall). A leak that cannot be sealed ends at
/// the leak bound with `stats.leaked`: the mesh is the balloon from before the leak began, its
/// vertices at the gap still Moving (flagged likewise), or, where no such balloon was kept,
/// `error` is set and the mesh empty.
/// @throws std::invalid_argument if `seed_mm` lies outside the volume, or for options out of range
///         (h·μ > 0.5 vox, h·λ ∉ [0, 1], non-positive edge length).
BalloonResult inflate_balloon(const volume::Volume& smoothed, const Vec3f& seed_mm,
                              const BalloonOptions& options = {}, std::stop_token stop = {});

/// The seed region's statistics on `smoothed` written into `stats`, as a balloon inflated there
/// would take them: seed_level, seed_sigma, tissue_level, noise_rise_per_mm, tau_cost_used and
/// tau_climb_used. Returns why the seed cannot start a balloon there, or empty. For a balloon
/// inflated on a coarser grid that stands for the pass on this one: the later stages and the
/// verdict then read this grid's levels. Same throws as inflate_balloon.
std::string measure_seed_region(const volume::Volume& smoothed, const Vec3f& seed_mm,
                                const BalloonOptions& options, BalloonStats& stats);

/// How far inside the previous balloon a warm start begins.
struct WarmStartOptions {
  float inset_mm = 0.0f;  // the erosion of its interior; at least 2 voxels (raised to that)
  // The start mesh's stop reasons (the previous balloon's): each wall it stopped at must still
  // be within inset_mm (more than 10 % gone: not safe). Empty: not checked.
  std::span<const StopReason> start_stop;
  // Each start vertex begins with the Ψ_cost and the darkest level of a path along its normal
  // from up to this far behind it (short of a wall behind), as if it had inflated from there,
  // so it stops where a cold start's vertex stops. 0: its cost is its net climb from the seed's
  // level alone (a warm start from the previous volume).
  float replay_vox = 0.0f;
};

/// The warm start (issue 17): the balloon starts inside `start_mesh` (the previous volume's
/// balloon, closed and genus 0; not a reconstructed surface, which may have a tunnel) instead of
/// from the small sphere at the seed. The walls it stopped at must still be there (start_stop);
/// its interior, rasterised on a voxel grid over its bounding box, without the cells its surface
/// passes through (so sheets that met behind a needle stay apart), is eroded by `inset_mm`; the
/// component at `seed_mm` must have a closed genus-0 surface, which is remeshed to the target
/// edge length; then every vertex and edge midpoint must lie inside the volume and below the
/// cost rule's wall level (the seed region's, from `seed_mm`, as in a cold start). A start that
/// fails is not used: the result has `start_unsafe` and `error` set and an empty mesh. A_t
/// starts empty (a withdrawn needle's tunnel is not carried from the old volume). Otherwise as
/// inflate_balloon, same throws.
BalloonResult inflate_balloon_from(const volume::Volume& smoothed, const Mesh& start_mesh,
                                   const Vec3f& seed_mm, const BalloonOptions& options = {},
                                   const WarmStartOptions& warm = {}, std::stop_token stop = {});

/// Limits of the second pass (reinflate).
struct ReinflateOptions {
  float max_move_vox = 1.5f;  // no vertex moves further: the pass gives back what the
                              // reconstruction's smoothing took from thin parts (under a voxel),
                              // it does not segment anew
  int max_iterations = 12;    // 1.5 vox at the default 0.3 vox per iteration takes 5
};

/// The paper's remedy for the thin spots where the topology changed (method.md, beyond the
/// paper): a second, short balloon pass that starts from the reconstructed closed surface (any
/// genus) and inflates it to the boundary again. The connectivity is fixed (no remeshing), so the
/// genus stays; the move bound stands in for the self-intersection test. The stop rule and its
/// thresholds are the first pass's (`first_pass` holds them), with the paper's dot-product rise
/// (rise_per_axis applies to the first pass only): each vertex starts with the cost of
/// the climb from the seed level to where it stands, and one already above the wall's mid level
/// stays. Stop reasons as for the balloon (IterationLimit: moved max_move_vox).
/// @throws std::invalid_argument if `surface` is not closed and manifold, or if `first_pass` has
///         no seed statistics.
BalloonResult reinflate(const volume::Volume& smoothed, const Mesh& surface,
                        const BalloonStats& first_pass, const BalloonOptions& options = {},
                        const ReinflateOptions& pass = {}, std::stop_token stop = {});

/// Options of fit_to_wall.
struct WallFitOptions {
  float reach_vox = 2.5f;  // the profile along each vertex normal, either way
  float step_vox = 0.5f;   // its sample spacing
  int rings = 3;           // the profiles are averaged over the vertex's neighbours this often
  float max_move_vox = 1.0f;
  float min_rise_fraction = 0.25f;  // of (tissue_level - seed_level): less is no wall
  /// A probe's apex, where its sector gives one. A wall the beam runs along (not faces_probe)
  /// returns little echo of its own and the tissue beside it reads dark (dropout): the image
  /// rises from the wall but reaches half way only beyond it, so those vertices cross at
  /// `along_beam_fraction` of the way instead of half (docs/stopping.md item 13).
  std::optional<Vec3f> probe_apex_mm;
  float along_beam_fraction = 0.45f;
};

/// Whether the wall at `p_mm` with unit normal `normal` faces the probe whose apex is `apex_mm`:
/// the beam meets it within 45° of square (|cos| over 0.7).
inline bool faces_probe(const Vec3f& p_mm, const Vec3f& normal, const Vec3f& apex_mm) {
  return std::abs((p_mm - apex_mm).normalized().dot(normal)) > 0.7f;
}

/// Beyond the paper: each vertex of `surface` moves along its normal to where the image,
/// averaged over the surface around it, crosses half way from its lowest level behind the vertex
/// to its highest ahead (or, along a probe's beam, WallFitOptions::along_beam_fraction of the
/// way). A single vertex's profile crosses on a speckle grain; the average over
/// the rings crosses on the wall. Connectivity is kept. `first_pass` gives the levels that tell
/// a wall from none. `threads` as BalloonOptions::threads.
/// @throws std::invalid_argument for an empty volume, a triangle index out of range, a
///         `first_pass` without seed statistics or options out of range.
Mesh fit_to_wall(const volume::Volume& smoothed, const Mesh& surface,
                 const BalloonStats& first_pass, const WallFitOptions& options = {},
                 int threads = 0);

/// Convenience: smooths `image` with a Gaussian of `sigma_mm`, inflates.
BalloonResult inflate_balloon(const volume::Volume& image, float sigma_mm, const Vec3f& seed_mm,
                              const BalloonOptions& options = {}, std::stop_token stop = {});

using mesh::euler_characteristic;

}  // namespace sonomesh::segment
