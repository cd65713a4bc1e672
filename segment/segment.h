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
#include <cstddef>
#include <cstdint>
#include <stop_token>
#include <string>
#include <vector>

#include "segment/mesh.h"
#include "volume/volume.h"

namespace sonomesh::segment {

struct BalloonOptions {
  // --- Evolution (explicit Euler) ---
  float time_step = 1.0f;         // h, per iteration (dimensionless time)
  float inflation_vox = 0.3f;     // μ, vox per unit time. h·μ is the outward step per iteration
                                  // and must stay <= 0.5 vox so no wall is jumped over.
  float umbrella_weight = 0.2f;   // λ, per unit time: fraction of the way to the neighbours'
                                  // centroid per unit time. h·λ must be in [0, 1] (stability).
  float initial_radius_vox = 2.0f;  // S^0 radius; shrunk (down to 1 vox) if the sphere would
                                    // reach brighter tissue or leave the volume.

  // --- Stop indicators ---
  bool relative_cost = true;      // accumulate Ψ_cost in a relative scale: each rise divided by
                                  // the intensity it starts from (floored at 10 % of the tissue
                                  // level), i.e. the rise of log I. Ultrasound attenuation and
                                  // acoustic shadows are multiplicative, so a wall in a needle's
                                  // shadow then costs as much as a bright one. false: grey levels,
                                  // the paper's plain Ψ_cost.
  float tau_cost = 0.0f;          // τ_cost in the cost's scale (grey levels if !relative_cost);
                                  // 0 = derive from the image around the seed:
                                  // F(seed + tau_cost_fraction · (tissue − seed)) − F(seed).
  float tau_cost_fraction = 0.5f; // used when tau_cost == 0: the climb to this fraction of the way
                                  // from the seed level to the tissue level, in grey levels
                                  // (0.5: the wall's mid level, where a step edge lies after
                                  // smoothing), measured in the cost's scale F
  float climb_backstop_fraction = 0.6f;  // P also stops once the image at P has risen above the
                                  // darkest level on P's path by the climb to this fraction
                                  // (mapped like tau_cost_fraction): a wall whose rise Ψ_cost
                                  // under-counted still stops P within it, so a leak never runs
                                  // on through the tissue
  float cost_window_vox = 10.0f;  // Departure from the paper's plain sum: Ψ_cost leaks, i.e. each
                                  // step first multiplies it by exp(−|step|/W) (W this window),
                                  // then adds the step's rise. A wall's rise (a few voxels wide
                                  // after smoothing) is kept almost whole, while the speckle
                                  // collected over a long path (the far side of a torus's tube)
                                  // decays instead of adding up to τ_cost. 0 = the plain sum.
  bool rise_per_axis = true;      // Departure from the paper's Ψ_cost increment max(0, <∇I, d>):
                                  // the sum over the grid axes of max(0, ∂_a I · d_a), so a fall
                                  // along one axis does not cancel a rise along another. Below a
                                  // needle its acoustic shadow darkens the image across the
                                  // shadow's edge, which runs along the beam (z) and, for a needle
                                  // inserted in a probe plane, along a second grid axis; where a
                                  // vertex crosses the cyst wall and that edge together, the dot
                                  // product netted the two and the wall cost too little (80³
                                  // cyst-needle, seeds 1-6: worst vertex 1.9-2.7 voxels outside
                                  // the staircase wall; with the split 0.7-1.5). The split also
                                  // counts speckle's mixed-sign steps, so lit walls stop ~0.15
                                  // voxel earlier (snap_to_wall gives that back).
                                  // Allowing for that extra speckle in τ_cost was measured and
                                  // let 256³ balloons leak along the needle. false: the paper's
                                  // dot product.
  bool noise_allowance = false;   // P stops when Ψ_cost(P) > τ_cost + ρ·path(P), ρ the rate at
                                  // which speckle alone raises Ψ_cost inside the target (measured
                                  // on the rays from the seed), path(P) the distance P travelled;
                                  // with a cost window W, ρ·W·(1 − exp(−path/W)). Off by default:
                                  // the short window bounds what speckle adds, and the allowance
                                  // let vertices that had passed a wall run on in the tissue
                                  // (same speckle rate there) and over-shoot by ~0.3 voxel.
  bool snap_to_wall = true;       // Departure from the paper: a vertex the boundary cost (or the
                                  // climb backstop) stops ends on the wall itself, the peak of the
                                  // image's slope <∇I, n> along its normal nearest to where it
                                  // stopped, within [−snap_back_vox, +snap_ahead_vox] (for a
                                  // smoothed step edge, its mid level). Ψ_cost only says that a
                                  // wall is near: where it crosses τ_cost also depends on the
                                  // speckle it collected on the way. Spheres at 64³ and 96³, 11
                                  // speckle seeds each: mean error −0.31 / −0.42 voxel (inside),
                                  // worst −1.21 / −1.36, 4 of 22 balloons with every vertex within
                                  // a voxel; snapped −0.09 / −0.04, worst +1.07 / +1.32, 19 of 22
                                  // (the rest: single vertices where speckle moved the image's own
                                  // edge); with L = 1.75 (below) 21 of 22, worst 1.02. No peak in
                                  // the window, or one below snap_min_slope: no wall there, the
                                  // vertex stays. Both passes snap; reinflate no further ahead
                                  // than its move bound.
  float snap_back_vox = 1.0f;     // the window behind the stop (vertices that over-shot)...
  float snap_ahead_vox = 1.5f;    // ...and ahead of it: speckle stops vertices early more often
                                  // and further than late; back + ahead <= 8
  float snap_min_slope = 0.25f;   // the peak's least relative slope <∇I, n>/I, per voxel (I
                                  // floored at 10 % of the tissue level): speckle inside a target
                                  // stays below (99 % below 0.16, highest 0.22 in 64³-128³
                                  // phantoms), the phantoms' walls peak at ~0.38, in a needle's
                                  // shadow too (it scales slope and level alike)
  float tau_curv = 1.2f;          // τ_curv: mean over P's edges of H(PQ)/|PQ| (dimensionless;
                                  // = |n₁−n₂|·sin∠, 0 flat, 2 folded back); stop above
  float self_intersection_cos = -0.5f;  // a marked voxel is "the other side" if the normal of
                                        // the front that marked it and P's normal have a cosine
                                        // below this (fronts meeting head-on have about −1)

  // --- Remeshing ---
  float target_edge_vox = 1.75f;  // L: split edges > 4/3 L, collapse edges < 4/5 L. 1.75 rather
                                  // than 1.5: a quarter fewer vertices and instructions, and the
                                  // same accuracy (68 pipeline cases, 64³-128³: genus right in
                                  // all, mean Dice 0.976 either way; spheres within a voxel 21 of
                                  // 22 instead of 19), except on the finest features: the 64³
                                  // double torus (holes 8 voxels across) loses 0.01-0.02 Dice at
                                  // contrast 0.9 or speckle 0.8 (not at 96³). At 2.0 it lost more.
  int remesh_every_iterations = 5;

  // --- Termination ---
  int max_iterations = 2000;      // remaining moving vertices then get IterationLimit
  float max_area_fraction = 1.0f; // a leak bound: a balloon with more vertices than a surface of
                                  // this fraction of the volume's bounding-box area needs has
                                  // escaped through a gap; it ends with `error` set
  int stall_window_iterations = 20;  // stop when no moving vertex got further than
  float stall_motion_vox = 0.02f;    // stall_motion_vox per iteration over this window

  int threads = 0;                // 0 = all hardware threads, 1 = serial
};

struct BalloonStats {
  int iterations = 0;
  std::array<int, 5> stop_counts{};  // vertices per StopReason (indexed by its value)
  float tau_cost_used = 0.0f;        // in the cost's scale (grey levels if !relative_cost)
  float tau_climb_used = 0.0f;       // the climb backstop's threshold, same scale
  float seed_level = 0.0f;           // mean smoothed intensity around the seed
  float seed_sigma = 0.0f;           // its standard deviation
  float tissue_level = 0.0f;         // estimated surrounding tissue level (ray sampling)
  float noise_rise_per_mm = 0.0f;    // ρ, grey levels per mm
  float initial_radius_mm = 0.0f;
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
  bool stalled = false;             // ended because nothing moved any more
  bool cancelled = false;           // ended because the stop_token was triggered
  bool leaked = false;              // ended at the leak bound (max_area_fraction); error set
  std::size_t front_voxels = 0;     // voxels in A_t (swept by the front) at the end
  std::size_t front_grid_bytes = 0; // memory of A_t's sparse grid
};

struct BalloonResult {
  Mesh mesh;                        // closed, manifold, genus 0, outward oriented (mm)
  std::vector<StopReason> stop;     // per vertex of mesh
  BalloonStats stats;
  bool converged = false;           // every vertex stopped, or the evolution stalled
  std::string error;                // non-empty: why there is no balloon (mesh empty then)
};

/// Inflates the balloon from `seed_mm` in a volume the caller has already smoothed (method.md
/// §0), with the central-difference gradient of that smoothed volume (same grid).
/// A seed that is not in a hypoechoic region (brighter than or as bright as its surroundings,
/// e.g. on the needle or in tissue), or a balloon that leaks out of its target (leak bound),
/// gives a result with `error` set and an empty mesh.
/// @throws std::invalid_argument if `seed_mm` lies outside the volume, if the gradient's grid
///         differs from the volume's, or for options out of range (h·μ > 0.5 vox, h·λ ∉ [0, 1],
///         non-positive edge length).
BalloonResult inflate_balloon(const volume::Volume& smoothed, const volume::Gradient& gradient,
                              const Vec3f& seed_mm, const BalloonOptions& options = {},
                              std::stop_token stop = {});

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
/// @throws std::invalid_argument if `surface` is not closed and manifold, if the gradient is not
///         Float32 on the volume's grid, or if `first_pass` has no seed statistics.
BalloonResult reinflate(const volume::Volume& smoothed, const volume::Gradient& gradient,
                        const Mesh& surface, const BalloonStats& first_pass,
                        const BalloonOptions& options = {}, const ReinflateOptions& pass = {},
                        std::stop_token stop = {});

/// Convenience: smooths `image` with a Gaussian of `sigma_mm`, takes its gradient, inflates.
BalloonResult inflate_balloon(const volume::Volume& image, float sigma_mm, const Vec3f& seed_mm,
                              const BalloonOptions& options = {}, std::stop_token stop = {});

/// Genus-0 check helper for callers and tests: V − E + F of a closed triangle mesh.
int euler_characteristic(const Mesh& mesh);

}  // namespace sonomesh::segment
