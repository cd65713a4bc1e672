#pragma once
/// @file
/// @brief The coarse-to-fine cold start (issue 17): the balloon inflates on the smoothed volume
/// downsampled by two, then a short warm start at full resolution takes it to the wall, where the
/// coarse balloon cannot stand for that pass.

#include <stop_token>
#include <string>
#include <vector>

#include "daemon/pipeline.h"
#include "segment/segment.h"
#include "volume/volume.h"

namespace sonomesh::daemon::internal {

struct CoarseStartOptions {
  float inset_vox = 2.0f;  // a finer pass starts this far inside the coarser balloon (its voxels)
  // Its vertices start with the cost and darkest level of this much path behind them
  // (segment::WarmStartOptions::replay_vox).
  float replay_vox = 40.0f;
  // Every pass tests for a stall this often (BalloonOptions::stall_window_iterations, when that
  // is longer): the few vertices that crawl in a crease, split off and melted back by the
  // remeshing, end its tail sooner; what a coarse pass leaves short, the finer one inflates.
  int stall_window_iterations = 10;
  int min_coarse_vox = 48;  // every axis of a coarse grid needs this many voxels, else no
                            // coarse pass (a target of a few coarse voxels loses its tunnels)
  int max_levels = 2;       // halvings at most
  // A finer pass may grow the surface to this many times the coarser balloon's area; more is a
  // leak (BalloonOptions::max_area_mm2): one through a gap the coarse grid blurred shut ran
  // to the volume's bound, 39 000 vertices, for 400-630 ms before the plain cold start.
  float max_area_growth = 3.0f;
  // The full-resolution pass only where the pass above it cannot stand for it
  // (stands_for_finest in coarse_start.cpp); false: always.
  bool finest_when_needed = true;
  // A coarser grid than this many voxels per axis never stands for the full resolution: it
  // blurs detail past what the reinflation and the wall fit take back (a 96³ echo lv's 48³).
  int stand_in_min_vox = 64;
};

/// The options `config`'s coarse_start_* fields set (the rest as CoarseStartOptions has them).
CoarseStartOptions coarse_start_options(const PipelineConfig& config);

/// What the coarse-to-fine start did, for the report and the benchmarks (fine_ms: every finer
/// pass, and the plain cold start when it ran instead).
using CoarseStartReport = PipelineResult::CoarseStart;

/// `smoothed` (Float32) averaged over 2×2×2 blocks into `coarse` (reused when it has the size):
/// the spacing doubles, the origin moves to the first block's centre, an odd last slab is
/// dropped. Returns false (and leaves `coarse` alone) when an axis would have fewer than
/// `min_vox` voxels or `smoothed` is not Float32.
bool downsample_by_two(const volume::Volume& smoothed, int min_vox, volume::Volume& coarse);

/// The cold start, coarse to fine: `smoothed` halved while every axis keeps min_coarse_vox
/// voxels (max_levels times at most, into `pyramid`, reused), segment::inflate_balloon on the
/// coarsest grid (the options are in voxels, so every step covers twice the distance and the
/// mesh has a quarter of the vertices), then segment::inflate_balloon_from on each finer grid
/// from the coarser balloon eroded by the inset, its walls checked against the coarser stops.
/// Each finer pass's A_t starts empty and its start has the seams where the coarser fronts met
/// opened, so the fronts meet again on the finer grid and mark the tunnels there. An attempt
/// that is refused, leaks or gives an unsafe start is retried from the next finer grid, and the
/// plain segment::inflate_balloon on `smoothed` comes last (report.fallback_reason says why), so a
/// volume the coarse grids cannot segment costs only the failed attempts. With
/// finest_when_needed the pass on `smoothed` itself is left out where the balloon above it can
/// stand for it (report.finest_skipped): the result's stats are then `smoothed`'s seed levels.
segment::BalloonResult coarse_to_fine_balloon(const volume::Volume& smoothed,
                                              std::vector<volume::Volume>& pyramid,
                                              const volume::Vec3f& seed_mm,
                                              const segment::BalloonOptions& options,
                                              const CoarseStartOptions& coarse_options,
                                              const std::stop_token& stop,
                                              CoarseStartReport& report);

}  // namespace sonomesh::daemon::internal
