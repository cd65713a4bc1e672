// Checks of the balloon's inputs (step.h).
#include <stdexcept>
#include <string>

#include "segment/internal/step.h"

namespace sonomesh::segment::internal {

const volume::Volume& as_float32(const volume::Volume& v, volume::Volume& storage) {
  if (v.type() == volume::VoxelType::Float32) return v;
  storage = volume::Volume(v.dims(), v.spacing_mm(), v.origin_mm(), volume::VoxelType::Float32);
  storage.f32() = v.to_float();
  return storage;
}

void check_options(const BalloonOptions& o) {
  if (const std::string problem = validate(o); !problem.empty())
    throw std::invalid_argument("BalloonOptions: " + problem);
}

}  // namespace sonomesh::segment::internal

namespace sonomesh::segment {

std::string validate(const BalloonOptions& o) {
  if (!(o.time_step > 0.0f)) return "time_step must be > 0";
  if (!(o.inflation_vox > 0.0f)) return "inflation_vox must be > 0";
  if (o.time_step * o.inflation_vox > 0.5f)
    return "time_step * inflation_vox must be <= 0.5 voxel (no wall may be jumped over)";
  if (!(o.umbrella_weight >= 0.0f) || o.time_step * o.umbrella_weight > 1.0f)
    return "time_step * umbrella_weight must be in [0, 1] (explicit Euler stability)";
  if (!(o.initial_radius_vox >= 1.0f)) return "initial_radius_vox must be >= 1";
  if (!(o.tau_cost >= 0.0f)) return "tau_cost must be >= 0 (0 = derive from the image)";
  if (!(o.tau_cost_fraction > 0.0f && o.tau_cost_fraction < 1.0f))
    return "tau_cost_fraction must be in (0, 1)";
  if (!(o.climb_backstop_fraction > 0.0f && o.climb_backstop_fraction <= 1.0f))
    return "climb_backstop_fraction must be in (0, 1]";
  if (!(o.region_fraction >= 0.0f && o.region_fraction < 1.0f))
    return "region_fraction must be in [0, 1) (0 = off)";
  if (!(o.level_stop_fraction >= 0.0f && o.level_stop_fraction < 1.0f))
    return "level_stop_fraction must be in [0, 1) (0 = off)";
  if (!(o.tau_curv > 0.0f)) return "tau_curv must be > 0";
  if (!(o.self_intersection_cos >= -1.0f && o.self_intersection_cos <= 1.0f) ||
      !(o.crumple_self_intersection_cos >= -1.0f && o.crumple_self_intersection_cos <= 1.0f))
    return "self_intersection_cos and crumple_self_intersection_cos must be in [-1, 1]";
  if (!(o.snap_back_vox >= 0.0f) || !(o.snap_ahead_vox >= 0.0f) ||
      !(o.snap_back_vox + o.snap_ahead_vox <= 8.0f))
    return "snap_back_vox and snap_ahead_vox must be >= 0 with a sum <= 8";
  if (!(o.snap_min_slope >= 0.0f)) return "snap_min_slope must be >= 0";
  if (!(o.cost_window_vox >= 0.0f)) return "cost_window_vox must be >= 0 (0 = plain sum)";
  if (!(o.target_edge_vox > 0.0f)) return "target_edge_vox must be > 0";
  if (o.remesh_every_iterations < 1) return "remesh_every_iterations must be >= 1";
  if (o.max_iterations < 1) return "max_iterations must be >= 1";
  if (!(o.max_area_fraction > 0.0f)) return "max_area_fraction must be > 0";
  if (!(o.max_area_mm2 >= 0.0f)) return "max_area_mm2 must be >= 0 (0 = no bound)";
  if (o.max_leak_seals < 0) return "max_leak_seals must be >= 0";
  if (o.stall_window_iterations < 1) return "stall_window_iterations must be >= 1";
  if (o.swept_out_windows < 0) return "swept_out_windows must be >= 0";
  if (o.threads < 0) return "threads must be >= 0";
  return {};
}

}  // namespace sonomesh::segment
