// The per-volume report (DESIGN.md "--report"), shared by `process` and `run`.
#include <cmath>

#include "daemon/pipeline.h"

namespace sonomesh::daemon {
namespace {

nlohmann::json vec_json(const Vec3f& v) { return {v.x(), v.y(), v.z()}; }
nlohmann::json vec_json(const Vec3i& v) { return {v.x(), v.y(), v.z()}; }

// The report's balloon section: iterations, thresholds, levels, stop reasons, and how it ended.
nlohmann::json balloon_json(const PipelineResult& result) {
  const StopCounts& s = result.stop_counts;
  nlohmann::json balloon = {{"iterations", result.balloon_iterations},
                            {"converged", result.balloon_converged},
                            {"tau_cost", result.balloon_stats.tau_cost_used},
                            {"seed_level", result.balloon_stats.seed_level},
                            {"seed_sigma", result.balloon_stats.seed_sigma},
                            {"tissue_level", result.balloon_stats.tissue_level},
                            {"vertices", result.balloon.vertices.size()},
                            {"faces", result.balloon.triangles.size()},
                            {"stop_reasons",
                             {{"moving", s.moving},
                              {"boundary", s.boundary},
                              {"curvature", s.curvature},
                              {"self_intersection", s.self_intersection},
                              {"iteration_limit", s.iteration_limit}}},
                            {"opened_points", result.opened_points}};
  // Ended before the limit because it swept nothing new: its movers count as at the limit.
  if (result.balloon_stats.swept_out) balloon["swept_out"] = true;
  // A leaked balloon's surface is the one from before the leak (quality "leak bound").
  if (result.balloon_stats.leaked)
    balloon["leak_rollback_iteration"] = result.balloon_stats.leak_rollback_iteration;
  // A sealed leak's vertices at the gap stopped there, not on a wall (docs/stopping.md).
  if (result.balloon_stats.leak_seals > 0) {
    balloon["leak_seals"] = result.balloon_stats.leak_seals;
    balloon["sealed_vertices"] = result.balloon_stats.sealed_vertices;
  }
  // The balloon crumpled and inflated again with the stricter self-intersection test.
  if (result.balloon_stats.crumple_restarts > 0)
    balloon["crumple_restarts"] = result.balloon_stats.crumple_restarts;
  return balloon;
}

}  // namespace

Vec3i seed_index_of(const volume::Volume& input, const Vec3f& seed_mm) {
  return input.mm_to_index(seed_mm).array().round().cast<int>();
}

nlohmann::json report_json(const PipelineResult& result, const std::string& input_name,
                           const volume::Volume& input, const Vec3f& seed_mm) {
  using nlohmann::json;
  json report;
  report["input"] = {{"path", input_name},
                     {"dims", vec_json(input.dims())},
                     {"spacing_mm", vec_json(input.spacing_mm())},
                     {"origin_mm", vec_json(input.origin_mm())},
                     {"type", volume::to_string(input.type())}};
  report["seed"] = {{"index", vec_json(seed_index_of(input, seed_mm))}, {"mm", vec_json(seed_mm)}};
  report["ok"] = result.ok;
  if (!result.ok) report["error"] = result.error;
  report["target"] = to_string(result.target);
  report["quality"] = result.quality_ok ? "ok" : "suspect";
  report["quality_reasons"] = result.quality_reasons;
  if (result.wall_support >= 0.0f) report["wall_support"] = result.wall_support;
  if (result.open_patch >= 0.0f) report["open_patch"] = result.open_patch;
  report["start"] = result.warm_start ? "warm" : "cold";
  report["stop_rule"] = result.stop_rule;
  report["second_opinion"] = result.second_opinion;
  if (!result.start_reason.empty()) report["start_reason"] = result.start_reason;
  if (const PipelineResult::CoarseStart& c = result.coarse_start; c.used)
    report["coarse_start"] = {{"downsample_ms", c.downsample_ms},
                              {"coarse_ms", c.coarse_ms},
                              {"fine_ms", c.fine_ms},
                              {"coarse_iterations", c.coarse_iterations},
                              {"levels", c.levels},
                              {"finest_skipped", c.finest_skipped}};
  else if (!c.fallback_reason.empty())
    report["coarse_start"] = {{"fallback_reason", c.fallback_reason}};
  report["smoothing"] = {{"sigma_mm", result.smooth_sigma_mm},
                         {"speckle_grain_mm", result.speckle_grain_mm},
                         {"coarse_retry", result.coarse_retry},
                         {"shadow_factor", result.shadow_factor},
                         {"shadow_voxels", result.shadow_voxels}};
  const StageTimings& t = result.timings;
  nlohmann::json& timings = report["timings_ms"];
  for (const auto& [stage, ms] : t.stages()) timings[stage] = ms;
  timings["labels"] = t.labels_ms;
  timings["total"] = t.total_ms;
  report["balloon"] = balloon_json(result);
  report["reconstruction"] = {{"grid", vec_json(result.grid_dims)},
                              {"cell_mm", result.grid_cell_mm}};
  if (result.dark_tunnels_closed) report["reconstruction"]["dark_tunnels_closed"] = true;
  if (result.tissue_columns_filled) report["reconstruction"]["tissue_columns_filled"] = true;
  if (result.needle_dent_filled) report["reconstruction"]["needle_dent_filled"] = true;
  report["reconstruction"]["resurfaced"] = result.resurfaced;
  if (result.bright_inside_opened) report["reconstruction"]["bright_inside_opened"] = true;
  // JSON has no infinity: the narrowest feature only when one was thin enough to matter.
  if (std::isfinite(result.grid_feature_mm))
    report["reconstruction"]["feature_mm"] = result.grid_feature_mm;
  report["mesh"] = {
      {"vertices", result.mesh.vertices.size()},  {"faces", result.mesh.triangles.size()},
      {"components", result.topology.components}, {"genus", result.topology.genus},
      {"watertight", result.topology.watertight}, {"volume_ml", result.enclosed_volume_ml}};
  if (result.deepest_interior_mm)
    report["deepest_interior_mm"] = vec_json(*result.deepest_interior_mm);
  return report;
}

}  // namespace sonomesh::daemon
