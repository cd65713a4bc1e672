// Surface tracking (track.h): the previous result's surface fitted to this volume's wall.
#include "daemon/internal/track.h"

#include <Eigen/Geometry>
#include <cmath>
#include <cstdio>
#include <exception>
#include <optional>
#include <utility>

#include "daemon/internal/bright_inside.h"
#include "daemon/internal/clock.h"
#include "daemon/internal/stages.h"
#include "daemon/internal/target_image.h"
#include "daemon/internal/track_anchor.h"

namespace sonomesh::daemon::internal {
namespace {

// How far beyond the previous surface tracking reads the smoothed image: the anchor where the
// last map put it lies within a voxel or so of that surface, its fits move it by up to three, the
// wall and open-patch tests look 5 voxels beyond the moved surface, a trilinear sample one more;
// the rest is slack for a remade surface's fit.
constexpr int kTrackedReachVox = 12;
// The surface's inside by ray parity (its labels) may differ from the volume it encloses by this
// share: more and it crosses itself (a fit pushed one sheet through another), which the signed
// volume hides and the labels do not; it is then reconstructed from its own samples before it is
// published. Along a chain of fits alone the share grew by 0.1-0.5 % a volume, at times 1.2-1.8 %
// at once.
constexpr double kMostInsideMismatch = 0.0075;
// How much larger the open patch may grow over the chain's first result: a withdrawn needle's
// tunnel adds 6.6-7.5 % of a cyst's area; a breathing 128³ cyst-needle's patch by the needle
// varies by up to 3 % (0.6-3.6 %).
constexpr float kMostOpenGrowth = 0.03f;
// How much it may grow from the last volume's: a needle withdrawn half-way adds 1.8 % at once
// (a 96³ cyst), within the limit above; breathing moves it by up to 0.7 % from one volume to the
// next (simple 96³ at 10 volumes/s; echo at most 0.2 %: each volume fits the chain's anchor).
constexpr float kMostOpenJump = 0.01f;
// A bright set with this share of the inside's voxels deep inside the tracked surface is a needle
// that came in: half of one pushed on from a dent has 0.6-0.9 % of a 96³ cyst's (simple, echo),
// a whole one more; echo speckle at most 0.14 % (48 voxels, a 40-volume 96³ stream).
constexpr double kLeastDeepBrightShare = 0.003;
// ... filling at least this much of one line (deep_on_a_line): needles fill 8.5 mm (half of one
// pushed on into a 96³ cyst) to 20 mm, the speckle web at contrast 0.5 mostly 2-6 mm, though as
// many deep voxels lie near its line as near a needle's.
constexpr float kLeastNeedleMm = 7.0f;
// Share of the area the fit may turn over (triangles whose normal reversed): marching cubes'
// slivers flip under any move (0.1-0.5 % of a 128³ cyst's area), a fold along the normals where
// the wall moved further than the surface's curvature allows turns more, and the surface is
// then reconstructed from its own samples.
constexpr double kMostFoldedShare = 0.02;

// The previous result's deepest point moved as the surface's centroid moved, on the nearest
// voxel centre as the deepest point of χ is: breathing moves a target, but hardly changes it.
std::optional<Vec3f> moved_with(const PipelineResult& previous, const segment::Mesh& surface,
                                const volume::Volume& input) {
  if (!previous.deepest_interior_mm) return std::nullopt;
  const Vec3f moved_mm = *previous.deepest_interior_mm + vertex_centroid_mm(surface) -
                         vertex_centroid_mm(previous.mesh);
  return input.index_to_mm(input.mm_to_index(moved_mm).array().round().matrix());
}

std::string percent(float share) {
  char text[32];
  std::snprintf(text, sizeof text, "%.1f %%", 100.0 * share);
  return text;
}

// (Labels' volume − enclosed volume) / enclosed volume.
double inside_mismatch(const volume::Volume& labels, double enclosed_ml) {
  std::size_t inside = 0;
  for (const std::uint8_t v : labels.u8()) inside += v != 0;
  const double labels_ml = static_cast<double>(inside) * labels.spacing_mm().prod() * 1e-3;
  return enclosed_ml > 0.0 ? labels_ml / enclosed_ml - 1.0 : 1.0;
}

// Share of the surface's area in triangles the fit turned over (their normal reversed).
double folded_share(const segment::Mesh& before, const segment::Mesh& after) {
  double folded = 0.0, total = 0.0;
  for (const auto& t : before.triangles) {
    const Vec3f a = (before.vertices[t[1]] - before.vertices[t[0]])
                        .cross(before.vertices[t[2]] - before.vertices[t[0]]);
    const Vec3f b = (after.vertices[t[1]] - after.vertices[t[0]])
                        .cross(after.vertices[t[2]] - after.vertices[t[0]]);
    total += b.norm();
    folded += a.dot(b) < 0.0f ? b.norm() : 0.0;
  }
  return total > 0.0 ? folded / total : 0.0;
}

// A surface a fit pushed through itself, made one surface again: resurfaced, as the pipeline's
// final surface is, and the wall fit once more. Unset where that lost the seed or the previous
// result's genus.
std::optional<reconstruct::SurfaceResult> remade(
    const volume::Volume& input, const volume::Volume& smoothed, const segment::Mesh& crossed,
    const PipelineResult& previous, const Vec3f& seed_mm, const PipelineConfig& config) {
  std::optional<reconstruct::SurfaceResult> s =
      resurfaced(input, crossed, previous.topology.genus, seed_mm, config);
  if (s)
    s->mesh = segment::fit_to_wall(smoothed, s->mesh, previous.balloon_stats,
                                   config.wall_fit_options, config.balloon.threads);
  return s;
}

// `again`'s surface as `tracked`'s, with its topology, enclosed volume and labels.
void take_surface(const volume::Volume& input, const reconstruct::SurfaceResult& again,
                  PipelineResult& tracked) {
  tracked.mesh = again.mesh;
  tracked.topology = again.topology;
  tracked.topology.volume_ml = reconstruct::enclosed_volume_ml(tracked.mesh);
  tracked.enclosed_volume_ml = tracked.topology.volume_ml;
  tracked.labels = reconstruct::rasterize_labels(tracked.mesh, input);
}

// `result`'s surface as the anchor of the chain from here, its maps none. An anchor whose own fit
// fails is none (the next volume's balloon says why it did not track): the result stands.
void start_chain_at(const volume::Volume& smoothed, const PipelineConfig& config,
                    PipelineResult& result) {
  try {
    result.tracking.anchor = make_anchor(smoothed, result, config);
  } catch (const std::exception&) {
    result.tracking.anchor.reset();
  }
  result.tracking.map = result.tracking.last_map = {};
}

// The labels of `tracked`'s surface, when it is not `folded` and they agree with the volume it
// encloses (see kMostInsideMismatch); else the surface the fits folded or pushed through itself
// is remade (`remade`) and checked again. Returns why not, or empty.
std::string label_consistently(const volume::Volume& input, const volume::Volume& smoothed,
                               const PipelineResult& previous, const Vec3f& seed_mm,
                               const PipelineConfig& config, const std::string& folded,
                               PipelineResult& tracked) {
  tracked.labels = reconstruct::rasterize_labels(tracked.mesh, input);
  double mismatch = inside_mismatch(*tracked.labels, tracked.enclosed_volume_ml);
  if (folded.empty() && std::abs(mismatch) <= kMostInsideMismatch) return "";
  const auto t = Clock::now();
  const std::optional<reconstruct::SurfaceResult> again =
      remade(input, smoothed, tracked.mesh, previous, seed_mm, config);
  tracked.timings.reconstruct_ms = ms_since(t);  // (the journal's stage, with its wall fit)
  const std::string crossed = !folded.empty() ? folded
                                              : "the surface crosses itself (inside " +
                                                    percent(static_cast<float>(mismatch)) + ")";
  if (!again) return crossed;
  take_surface(input, *again, tracked);
  start_chain_at(smoothed, config, tracked);  // (its vertices are no longer the anchor's)
  tracked.start_reason = "previous surface, reconstructed";
  mismatch = inside_mismatch(*tracked.labels, tracked.enclosed_volume_ml);
  return std::abs(mismatch) <= kMostInsideMismatch ? "" : crossed + ", reconstructed too";
}

// The deep bright voxels on one line inside `result`'s surface (`labels` its inside), none when
// they are no solid structure (bright_inside.h).
DeepLine deep_bright_line(const volume::Volume& smoothed, const volume::Volume& labels,
                          const PipelineResult& result) {
  const InsideRegion inside =
      inside_labels(labels, mesh::bounding_box(result.mesh), result.balloon_stats);
  const BrightStructure bright = deepest_bright_structure(smoothed, inside);
  return solid_inside(bright) ? deep_on_a_line(smoothed, inside, bright) : DeepLine{};
}

// The previous result as this volume's, with this volume's smoothing and the fitted surface.
PipelineResult carried(const PipelineResult& previous, const PipelineResult& smoothed,
                       segment::Mesh surface) {
  PipelineResult r = previous;
  r.mesh = std::move(surface);
  r.labels.reset();
  r.indicator.reset();
  r.speckle_grain_mm = smoothed.speckle_grain_mm;
  r.smooth_sigma_mm = smoothed.smooth_sigma_mm;
  r.shadow_factor = smoothed.shadow_factor;
  r.shadow_voxels = smoothed.shadow_voxels;
  r.needle_ends_mm = smoothed.needle_ends_mm;
  r.timings = StageTimings{.smooth_ms = smoothed.timings.smooth_ms};
  r.balloon_iterations = 0;
  r.fitted_wall_support = -1.0f;  // (the verdict measures this volume's surface)
  r.second_opinion = r.unconfirmed = false;
  r.coarse_start = {};
  // (no reconstruction on this volume)
  r.dark_tunnels_closed = r.tissue_columns_filled = r.needle_dent_filled = false;
  r.bright_inside_opened = r.resurfaced = false;
  r.bright_inside_left = false;
  r.warm_start = true;
  r.start_reason = "previous surface";
  r.tracking.chain = previous.tracking.chain + 1;
  r.tracking.refused.clear();
  r.topology.volume_ml = reconstruct::enclosed_volume_ml(r.mesh);
  r.enclosed_volume_ml = r.topology.volume_ml;
  return r;
}

}  // namespace

std::string track_surface(const volume::Volume& input, const Vec3f& seed_mm,
                          const PipelineConfig& config, const PipelineBuffers& buffers,
                          const PipelineResult& previous, const Judge& judge,
                          PipelineResult& result) {
  if (previous.target != result.target) return "the polarity changed";
  if (!previous.topology.manifold || previous.tracking.open_patch_base < 0.0f)
    return "the previous result has no base to check against";
  if (!previous.tracking.anchor) return "the previous result gave no anchor to track from";
  const int threads = config.balloon.threads;
  const auto t = Clock::now();
  const segment::Mesh start = predicted_anchor(previous.tracking);
  segment::Mesh fitted = follow_wall(buffers.smoothed, start, previous.balloon_stats, config);
  // The open patch is the fit's as it stands: where this volume's wall is gone, as round a needle
  // withdrawn from its tunnel, the anchor's own fit says nothing, and taking it off there would
  // narrow the tunnel whose area the patch measures.
  const segment::BalloonStats& levels = previous.balloon_stats;
  const float open =
      open_patch(buffers.smoothed, fitted, levels.seed_level, levels.tissue_level, threads);
  take_off_own_fit(*previous.tracking.anchor, start, fitted);
  const double folded_area = folded_share(start, fitted);
  const std::string folded =
      folded_area > kMostFoldedShare ? "folded " + percent(static_cast<float>(folded_area)) : "";
  PipelineResult tracked = carried(previous, result, std::move(fitted));
  fit_anchor_map(tracked.mesh, input.spacing_mm().minCoeff(), tracked.tracking);
  tracked.timings.reinflate_ms = ms_since(t);
  tracked.deepest_interior_mm = moved_with(previous, tracked.mesh, input);
  tracked.open_patch = open;
  if (tracked.open_patch > previous.tracking.open_patch_base + kMostOpenGrowth)
    return "open patch " + percent(tracked.open_patch) + " from " +
           percent(previous.tracking.open_patch_base);
  if (previous.open_patch >= 0.0f && tracked.open_patch > previous.open_patch + kMostOpenJump)
    return "open patch " + percent(tracked.open_patch) + " from " + percent(previous.open_patch) +
           " on the last volume";
  const auto t_labels = Clock::now();
  if (std::string why =
          label_consistently(input, buffers.smoothed, previous, seed_mm, config, folded, tracked);
      !why.empty())
    return why;
  // Not only one across the target: a needle pushed on from a dent through the far wall adds
  // half of one (which the balloon, not the tracked surface, must open). Counted along one line:
  // at contrast 0.5 the blood pool's speckle above the mid level is a web through the whole
  // inside, with as many deep voxels near a line as a needle, but not filling it. Counted over
  // what the chain's first result held: the echo lv holds 200-310 such voxels on every volume.
  const double inside_vox = tracked.enclosed_volume_ml * 1e3 / input.spacing_mm().prod();
  const DeepLine line = deep_bright_line(buffers.smoothed, *tracked.labels, tracked);
  if (static_cast<double>(line.voxels - previous.tracking.bright_line_base) >
          kLeastDeepBrightShare * inside_vox &&
      line.length_mm >= kLeastNeedleMm)
    return "a bright structure inside, " + std::to_string(line.voxels) +
           " voxels deep on a line of " + std::to_string(std::lround(line.length_mm)) + " mm";
  if (!config.want_labels) tracked.labels.reset();
  tracked.timings.labels_ms = ms_since(t_labels) - tracked.timings.reconstruct_ms;
  judge(tracked, "");
  if (!tracked.quality_ok) return "suspect: " + tracked.quality_reasons.front();
  result = std::move(tracked);
  return "";
}

IndexBox tracked_region(const volume::Volume& input, const PipelineResult& previous) {
  if (previous.mesh.vertices.empty()) return {input.dims(), Vec3i::Constant(-1)};  // (none)
  const mesh::Box box = mesh::bounding_box(previous.mesh);
  const Vec3i lo = input.mm_to_index(box.lo_mm).array().floor().cast<int>();
  const Vec3i hi = input.mm_to_index(box.hi_mm).array().ceil().cast<int>();
  // (Reach in voxels of the finest axis, as the readers count it, on each axis's own spacing.)
  const Vec3f reach_mm = Vec3f::Constant(kTrackedReachVox * input.spacing_mm().minCoeff());
  const Vec3i reach = reach_mm.cwiseQuotient(input.spacing_mm()).array().ceil().cast<int>();
  return {(lo - reach).cwiseMax(0), (hi + reach).cwiseMin(input.dims() - Vec3i::Ones())};
}

void measure_tracking_base(const volume::Volume& input, const PipelineBuffers& buffers,
                           const PipelineConfig& config, PipelineResult& result) {
  const segment::BalloonStats& levels = result.balloon_stats;
  if (result.open_patch < 0.0f)
    result.open_patch = open_patch(buffers.smoothed, result.mesh, levels.seed_level,
                                   levels.tissue_level, config.balloon.threads);
  result.tracking.open_patch_base = result.open_patch;
  start_chain_at(buffers.smoothed, config, result);
  std::optional<volume::Volume> made;  // (the result's own labels when it has them, not a copy)
  if (!result.labels) made = reconstruct::rasterize_labels(result.mesh, input);
  result.tracking.bright_line_base =
      deep_bright_line(buffers.smoothed, result.labels ? *result.labels : *made, result).voxels;
}

std::string unfit_anchor(const PipelineResult& fresh, int tracked_genus) {
  if (!fresh.ok) return "not made: " + fresh.error;
  if (!fresh.quality_ok) {
    std::string why = "suspect";
    for (std::size_t i = 0; i < fresh.quality_reasons.size(); ++i)
      why += (i == 0 ? " (" : ", ") + fresh.quality_reasons[i];
    return fresh.quality_reasons.empty() ? why : why + ")";
  }
  // (The warm start keeps neither.)
  if (fresh.mesh.vertices.empty() || fresh.balloon.vertices.empty()) return "without a surface";
  if (fresh.topology.genus == tracked_genus) return {};
  return "of genus " + std::to_string(fresh.topology.genus) + " where the chain tracked " +
         std::to_string(tracked_genus);
}

}  // namespace sonomesh::daemon::internal

namespace sonomesh::daemon {

WarmStart warm_start_from(const PipelineResult& previous, float inset_mm) {
  auto kept = std::make_shared<PipelineResult>(previous);
  kept->labels.reset();
  kept->indicator.reset();
  return WarmStart{.balloon = previous.balloon,
                   .balloon_stop = previous.balloon_stop,
                   .inset_mm = inset_mm,
                   .genus = previous.topology.genus,
                   .level_stop = previous.stop_rule == "level",
                   .previous = std::move(kept),
                   .crumpled = previous.crumpled};
}

}  // namespace sonomesh::daemon
