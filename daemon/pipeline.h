#pragma once
/// @file
/// @brief The per-volume pipeline every sonomeshd mode runs: smooth, balloon, opening, Kazhdan
/// reconstruction, marching cubes, topology, labels (DESIGN.md, docs/method.md).

#include <array>
#include <cstdint>
#include <limits>
#include <memory>
#include <nlohmann/json.hpp>
#include <optional>
#include <stop_token>
#include <string>
#include <utility>
#include <vector>

#include "reconstruct/reconstruct.h"
#include "segment/mesh.h"
#include "segment/segment.h"
#include "volume/volume.h"

namespace sonomesh::daemon {

using volume::Mat3f;
using volume::Vec3f;
using volume::Vec3i;

namespace internal {
struct TrackingAnchor;
}

/// Polarity of the target (DESIGN.md "Targets, polarity and the quality verdict"): darker than
/// its surroundings (cyst, cardiac cavity), brighter (hyperechoic lesion, CT organ), or decided
/// from the seed region against its surroundings.
enum class TargetPolarity { Dark, Bright, Auto };

/// "dark", "bright", "auto".
const char* to_string(TargetPolarity target);

struct PipelineConfig {
  TargetPolarity target = TargetPolarity::Dark;
  /// Gaussian sigma of the pre-smoothing in mm. Unset: one voxel of the finest axis (0.5 mm on the
  /// simulator's grid), which removes single-voxel speckle without moving walls by more than a
  /// fraction of a voxel. 0 disables smoothing.
  std::optional<float> smooth_sigma_mm;
  segment::BalloonOptions balloon;
  reconstruct::PoissonOptions poisson;
  /// Reconstruct on a grid of the volume's finest voxel spacing (overrides poisson.cell_mm), as
  /// method.md §5 asks, finer where a thin feature needs it (poisson.min_feature_cells); the
  /// first reconstruction of a thick target up to 1.5 voxels when the wall fit and the resurface
  /// follow (docs/tuning.md, "Reconstruction"). false keeps poisson.cell_mm.
  bool cell_from_voxel = true;
  /// The second, short balloon pass from the reconstructed surface back to the boundary
  /// (segment::reinflate): gives back what the reconstruction's smoothing takes from thin parts.
  bool reinflate = true;
  segment::ReinflateOptions reinflate_pass;
  /// Beyond the paper (segment::fit_to_wall), after the reinflation: each vertex to where the
  /// image averaged over the surface around it crosses half way to the wall.
  bool wall_fit = true;
  segment::WallFitOptions wall_fit_options;
  /// After the wall fit, the fit once more on the image before its pre-filter (the working image:
  /// polarity, no data and shadows as the balloon saw them), its profiles averaged over 5 rings,
  /// then moved back to the volume the wall fit enclosed: the pre-filter blurs the wall along the
  /// normal as well as the speckle along the surface, the rings take the speckle only
  /// (docs/stopping.md item 13). Not in the coarse retry, whose fine fit follows.
  bool fit_unsmoothed = true;
  /// Beyond the paper, after the wall fit: the fitted surface made again from its own samples by
  /// Kazhdan's reconstruction, which smooths away the speckle grains the fit followed (the same
  /// genus, the seed inside; else the fitted surface stays).
  bool resurface = true;
  /// The second opinion (docs/stopping.md departure 9): a result the verdict calls suspect, or
  /// no result, is segmented again with the level stop at this fraction
  /// (segment::BalloonOptions::level_stop_fraction), and the better of the two is kept: the one
  /// the verdict calls ok, else the one with the larger wall support. 0 = off; not tried when
  /// balloon.level_stop_fraction is already set.
  float second_opinion_level_stop = 0.5f;
  /// A cold start in a probe's sector (a dark target whose no-data region has an apex) runs the
  /// level stop first and Ψ_cost as the second opinion: in echo the blood pool's speckle stops
  /// Ψ_cost short (docs/stopping.md departure 9).
  bool level_stop_first_in_sector = true;
  /// The coarse retry (docs/stopping.md departure 12): a result that stalled on the texture
  /// around the seed with both stop rules, or whose contrast the verdict calls low, is segmented
  /// again on the volume smoothed at this many speckle grains (clamped to 2-3 voxels); such a
  /// result is always suspect ("coarse pre-filter"). 0 = off; only with the automatic pre-filter
  /// and the second opinion on.
  float coarse_retry_grains = 2.2f;
  /// The cold start coarse to fine (issue 17): the balloon inflates on the smoothed volume
  /// averaged over 2×2×2 blocks, then a short warm start at full resolution takes it from there
  /// to the wall; it falls back to the plain cold start when the coarse pass fails. false: the
  /// plain cold start from the small sphere at full resolution.
  bool coarse_start = true;
  float coarse_start_inset_vox = 2.0f;  // the fine pass's inset, full-resolution voxels
  int coarse_start_min_vox = 48;        // least coarse voxels per axis (96³ inputs and up)
  int coarse_start_max_levels = 2;      // halvings at most (256³: 128³ and 64³)
  // The full-resolution pass only where the coarser balloon cannot stand for it: one that ended
  // clean without fronts that met, at a contrast that is not low (docs/tuning.md).
  bool coarse_start_finest_when_needed = true;
  int coarse_start_stand_in_min_vox = 64;  // least voxels per axis of a grid that stands in
  /// Surface tracking (issue 17): a warm volume fits the previous result's surface to this
  /// volume's wall (segment::fit_to_wall) instead of inflating a balloon and reconstructing, when
  /// the checks of daemon/internal/track.h pass; at most this many volumes in a row, then a cold
  /// start (the chain's balloon is too old to start from), which anchors the next (the daemon
  /// publishes the chain's last volume first: docs/tuning.md). 10: at 10 volumes/s chains of 20
  /// drifted out in the needle's shadow until the open patch refused them. 0 = off.
  int track_max_chain = 10;
  /// Acoustic shadows lifted before the balloon (docs/stopping.md item 17): in a probe's sector,
  /// what lies beyond a needle along the beam is multiplied back to the level beside it
  /// (daemon/internal/shadow_gain.h). false: the image as it came.
  bool shadow_gain = true;
  bool want_labels = true;      // label volume on the input grid (inside = 1); seed tracking
                                // does not need it (deepest_interior_mm comes from χ)
  bool want_indicator = false;  // the indicator function χ as a Float32 volume (for .vdb output)
};

/// Wall-clock time per stage in ms; `total` includes everything run_pipeline did. `labels` is the
/// deepest-point search (it runs alongside `reinflate`) plus, when labels are wanted, the
/// rasterization on the input grid (not one of the paper's stages).
struct StageTimings {
  double smooth_ms = 0, balloon_ms = 0, opening_ms = 0, reconstruct_ms = 0, mesh_ms = 0,
         reinflate_ms = 0, resurface_ms = 0, labels_ms = 0, total_ms = 0;

  /// The seven stages of the method by the names the report, the journal and /stats use
  /// (without `labels` and `total`), in pipeline order.
  std::array<std::pair<const char*, double>, 7> stages() const {
    return {{{"smooth", smooth_ms},
             {"balloon", balloon_ms},
             {"opening", opening_ms},
             {"reconstruct", reconstruct_ms},
             {"mesh", mesh_ms},
             {"reinflate", reinflate_ms},
             {"resurface", resurface_ms}}};
  }
};

/// Counts of balloon vertices per stop reason (segment::StopReason, the balloon PLY's codes).
struct StopCounts {
  int moving = 0, boundary = 0, curvature = 0, self_intersection = 0, iteration_limit = 0;
};

struct PipelineResult {
  bool ok = false;
  std::string error;  // one line, when !ok

  segment::Mesh mesh;              // final closed surface, mm
  reconstruct::Topology topology;  // of `mesh`
  double enclosed_volume_ml = 0.0;

  segment::Mesh balloon;                          // the balloon when evolution ended, mm
  std::vector<segment::StopReason> balloon_stop;  // per balloon vertex
  StopCounts stop_counts;
  int balloon_iterations = 0;
  bool balloon_converged = false;  // every vertex stopped or the evolution stalled
  segment::BalloonStats balloon_stats;
  int opened_points = 0;            // oriented samples left after the opening
  Vec3i grid_dims = Vec3i::Zero();  // reconstruction grid
  float grid_cell_mm = 0.0f;
  float grid_feature_mm = std::numeric_limits<float>::infinity();  // narrowest feature the
                                                                   // samples showed (infinity: none
                                                                   // thin enough to matter)

  /// The polarity the pipeline segmented with (never Auto: auto resolves to dark or bright).
  TargetPolarity target = TargetPolarity::Dark;
  /// The quality verdict: true is "ok"; false is "suspect", with short reasons (for example
  /// "stalled near the seed", "touches the volume edge", "leak bound", "implausibly small").
  bool quality_ok = true;
  std::vector<std::string> quality_reasons;
  /// Share of the final surface's vertices with a brighter wall just beyond them in the image the
  /// balloon saw (the verdict wants 3/4); −1 when not measured (no surface). Where the fit on the
  /// unsmoothed image ran, it is `fitted_wall_support`: that fit moves walls facing the probe off
  /// the smoothed image's blurred edge, which this test reads.
  float wall_support = -1.0f;
  float fitted_wall_support = -1.0f;  // the surface's before the unsmoothed fit; −1: not measured
  /// Share of the final surface's area in its largest patch that looks into the target's inside
  /// (measured on a cold result the verdict called ok, to ask for the second opinion); −1 when
  /// not measured.
  float open_patch = -1.0f;
  /// The speckle's grain measured around the seed and the pre-filter's sigma it chose (mm).
  float speckle_grain_mm = 0.0f;
  float smooth_sigma_mm = 0.0f;
  /// The acoustic shadow lifted (PipelineConfig::shadow_gain): its level over the level beside
  /// it (1: none found) and how many voxels were lifted.
  float shadow_factor = 1.0f;
  std::size_t shadow_voxels = 0;
  /// The ends of the needle that cast the shadow (ShadowGain::ends_mm), when one was found.
  std::optional<std::array<Vec3f, 2>> needle_ends_mm;
  /// The result comes from the coarse retry (PipelineConfig::coarse_retry_grains).
  bool coarse_retry = false;

  /// The balloon started from a warm start's mesh (false: from the sphere at the seed), and why
  /// a warm start that was asked for was not used (the pipeline's safety check said so).
  bool warm_start = false;
  std::string start_reason;
  /// Surface tracking (PipelineConfig::track_max_chain): `chain` volumes in a row were tracked,
  /// this one included (0: the balloon ran); the open patch of the chain's first result, which
  /// the tracked ones are checked against; why tracking was refused on this volume (empty: not
  /// refused, or not asked); and whether the balloon started cold because the warm start's
  /// balloon was a tracked chain's first, too old to start from.
  struct Tracking {
    int chain = 0;
    float open_patch_base = -1.0f;
    long bright_line_base = 0;  // deep bright voxels on a line inside the chain's first result
    std::string refused;
    bool balloon_stale = false;
    /// The chain's anchor (its first result's surface, internal/track_anchor.h), the affine map
    /// from it to this volume's wall, p -> linear (p - centre) + centre + shift with the centre
    /// the anchor's centroid, and the last volume's map.
    std::shared_ptr<const internal::TrackingAnchor> anchor;
    struct Map {
      Mat3f linear = Mat3f::Identity();
      Vec3f shift_mm = Vec3f::Zero();
    } map, last_map;
  } tracking;
  /// The balloon's stop rule behind this result: "cost" (Ψ_cost, the paper's) or "level" (the
  /// level stop, as configured or as the second opinion); and whether the second opinion ran.
  std::string stop_rule = "cost";
  bool second_opinion = false;
  /// The second opinion was asked of this ok result (it looked open or thin), and the other
  /// rule's result stalled near the seed, enclosed over twice its volume, spread its balloon
  /// over 2.5 times its box without a leak, or found a needle across a genus-0 result; or this
  /// result is the other rule's, taken after a suspect first, and looks open or is thin and
  /// genus 0. It may have stopped short in the target (the verdict says "not confirmed by the
  /// other stop rule").
  bool unconfirmed = false;
  /// The balloon crumpled (segment::BalloonStats::crumple_restarts), or started with the
  /// stricter self-intersection test because one before it in the stream had: the next volume's
  /// balloons start strict too, rather than crumple and inflate twice.
  bool crumpled = false;
  /// Tunnels through the target's own darkness, or sheets where the balloon's fronts met, were
  /// filled (reconstruct::close_dark_tunnels).
  bool dark_tunnels_closed = false;
  /// More handles than a target has: the tunnels round columns of tissue were filled too.
  bool tissue_columns_filled = false;
  /// A handle round no needle (the needle's tip lies inside the surface) was filled as a column
  /// of tissue's would be.
  bool needle_dent_filled = false;
  /// The final surface is the wall-fitted one made again from its samples
  /// (PipelineConfig::resurface).
  bool resurfaced = false;
  /// A bright structure the surface had passed over (a needle) was opened, its walls added to
  /// the reconstruction's samples (internal::open_bright_inside).
  bool bright_inside_opened = false;
  /// ...and the genus did not rise: its walls opened no tunnel (a needle too thin for the grid at
  /// this smoothing, or clutter across a cavity). The verdict says "bright structure inside".
  bool bright_inside_left = false;
  /// A cold start that ran coarse to fine (PipelineConfig::coarse_start), the parts' times (all
  /// within timings.balloon_ms), and why the plain cold start ran instead when it was tried.
  struct CoarseStart {
    bool used = false;
    std::string fallback_reason;
    double downsample_ms = 0.0, coarse_ms = 0.0, fine_ms = 0.0;
    int coarse_iterations = 0;
    int levels = 0;               // halvings of the coarsest grid
    bool finest_skipped = false;  // the balloon is the grid's above the input's
  } coarse_start;

  StageTimings timings;
  std::optional<volume::Volume> labels;     // UInt8 on the input grid, inside = 1
  std::optional<volume::Volume> indicator;  // Float32 χ − iso on the reconstruction grid
  /// The deepest point inside the result, for the daemon's seed tracking: the maximum of the
  /// distance transform of χ > iso on the reconstruction grid, in the part around the seed
  /// (internal::deepest_inside). Set whenever there is a surface, labels or not.
  std::optional<Vec3f> deepest_interior_mm;
  float deepest_depth_mm = 0.0f;  // its distance from the surface (0: none)
};

/// Runs the whole pipeline on one volume. Numerical outcomes (a balloon that found nothing, a
/// reconstruction without a surface around the seed, a stop request, a seed outside the volume)
/// come back as ok = false with a one-line error. The seed is not checked for bright tissue here:
/// callers run check_seed first (it costs a pass over the volume).
PipelineResult run_pipeline(const volume::Volume& input, const Vec3f& seed_mm,
                            const PipelineConfig& config, std::stop_token stop = {});

/// What one caller keeps from volume to volume (the daemon's worker): the smoothed volume and the
/// image smoothed when it is not the input, 4 bytes per voxel each, and a probe's no-data region.
/// A fresh volume is allocated and zero-filled for every volume, which at 256³ costs about as
/// much as the smoothing itself. (No gradient volumes: the balloon takes central differences
/// of the smoothed volume where it samples.)
struct PipelineBuffers {
  volume::Volume smoothed;
  std::vector<volume::Volume> pyramid;  // the coarse start's grids, an eighth of the one below
  // The image smoothed, where it is not the input itself; else, once the unsmoothed fit ran,
  // the input as Float32 (PipelineConfig::fit_unsmoothed).
  volume::Volume working;
  // A probe's no-data region (zeros outside its sector) and the plan of the working image's fill
  // over it: the same in every volume of a probe, so flooded again only when the zeros moved.
  struct NoDataRegion {
    Vec3i dims = Vec3i::Zero();
    std::vector<std::uint8_t> mask;  // per voxel (Volume::linear_index), 1: no data; empty: none
    std::vector<std::pair<std::uint32_t, std::uint32_t>> fill;  // (voxel, voxel it copies)
    std::optional<Vec3f> apex_mm;  // the probe's apex, when the region's walls meet in one point
  } no_data;
  // The index box (inclusive) of the voxels that cast the last volume's needle shadow, where a
  // tracked volume looks for them first (the shadow search's clusters cost 7 ms at 128³).
  std::optional<std::pair<Vec3i, Vec3i>> shadow_casters;
};

/// Same, smoothing into `buffers` (reused when the next volume has the same dimensions).
PipelineResult run_pipeline(const volume::Volume& input, const Vec3f& seed_mm,
                            const PipelineConfig& config, PipelineBuffers& buffers,
                            std::stop_token stop = {});

/// A warm start (issue 17): the previous volume's balloon (grid frame mm, closed, genus 0; not
/// the reconstructed surface, which may have a tunnel) and how far inside it the new balloon
/// starts (its interior is eroded by that much).
struct WarmStart {
  segment::Mesh balloon;
  std::vector<segment::StopReason> balloon_stop;  // per vertex: its walls must still be there
  float inset_mm = 0.0f;  // raised to at least 2 voxels (segment::WarmStartOptions)
  // The previous result's genus: a warm result of another genus is checked by a cold start
  // (the start's checks refuse a needle inserted or withdrawn before, so a warm start that
  // changes the genus is suspect). Unset: not checked.
  std::optional<int> genus;
  // The previous result came from the level stop (the second opinion's rule): the warm balloon
  // runs it too, and the second opinion, if needed, is then Ψ_cost's.
  bool level_stop = false;
  // The previous result (without labels or χ), whose surface is tracked on this volume when the
  // checks allow it (PipelineConfig::track_max_chain). Null: the balloon starts from `balloon`.
  std::shared_ptr<const PipelineResult> previous;
  // The previous result crumpled (PipelineResult::crumpled): the balloons start strict.
  bool crumpled = false;
};

/// The warm start the next volume takes from `previous` (an ok result): its balloon, eroded by
/// `inset_mm`, its genus and stop rule, and the result itself for tracking, its labels and χ left
/// out (they are not tracked, and are a volume's size each).
WarmStart warm_start_from(const PipelineResult& previous, float inset_mm);

/// Same, the balloon starting from `warm` when it is given and safe on this volume
/// (segment::inflate_balloon_from), else from the small sphere at the seed; the result says
/// which (`warm_start`, and `start_reason` when a given warm start was not safe).
PipelineResult run_pipeline(const volume::Volume& input, const Vec3f& seed_mm,
                            const PipelineConfig& config, PipelineBuffers& buffers,
                            const WarmStart* warm, std::stop_token stop = {});

/// Why `seed_mm` cannot start a balloon in `input` (outside the volume, or, for a dark target, in
/// bright tissue: the local mean around it is above the volume's Otsu threshold between dark target
/// and tissue; bright and auto check the bounds only, the balloon's own check decides), or nullopt
/// if it can. Used by `process` and by the daemon's seed tracking.
std::optional<std::string> check_seed(const volume::Volume& input, const Vec3f& seed_mm,
                                      TargetPolarity target = TargetPolarity::Dark);

/// Nearest voxel index of a point in mm (rounded).
Vec3i seed_index_of(const volume::Volume& input, const Vec3f& seed_mm);

/// The report of DESIGN.md: input, seed (index and mm), stage timings in ms, balloon iterations
/// and stop-reason counts, reconstruction grid size, output vertex/face counts, components, genus,
/// watertight, enclosed volume in mL. `input_name` is the path or the daemon's sequence label.
nlohmann::json report_json(const PipelineResult& result, const std::string& input_name,
                           const volume::Volume& input, const Vec3f& seed_mm);

}  // namespace sonomesh::daemon
