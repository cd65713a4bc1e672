// The fitted surface's last steps (stages.h): the fit once more on the unsmoothed image at the
// fitted volume (fit_unsmoothed), and the surface made again from its own samples (resurfaced),
// the wall fit's vertices through Kazhdan's reconstruction once more.
#include <algorithm>
#include <chrono>
#include <optional>
#include <utility>
#include <vector>

#include "daemon/internal/stages.h"

namespace sonomesh::daemon::internal {
namespace {

// First on cells this many times the configured ones (half the cells, and the coarser grid
// averages more of the speckle away), or a thick target's coarser ones, then on the configured
// ones where that lost the genus (a 2-voxel needle's tunnel may close; at 1.5 times for every
// target thin tubes were lost too: docs/stopping.md item 19).
constexpr float kCoarseCells = 1.25f;

}  // namespace

void keep_volume(segment::Mesh& surface, double has_ml, double volume_ml) {
  const double area_mm2 = mesh::surface_area_mm2(surface);
  if (!(area_mm2 > 0.0)) return;
  const auto out_mm = static_cast<float>((volume_ml - has_ml) * 1e3 / area_mm2);
  const std::vector<Vec3f> normal = mesh::vertex_normals(surface);
  for (std::size_t v = 0; v < normal.size(); ++v) surface.vertices[v] += out_mm * normal[v];
}

// Over more rings than the fit on the smoothed image: the unsmoothed image's speckle is finer.
constexpr int kUnsmoothedFitRings = 5;

void fit_unsmoothed(const volume::Volume& input, PipelineBuffers& buffers,
                    const PipelineConfig& config, PipelineResult& result) {
  const double fitted_ml = reconstruct::enclosed_volume_ml(result.mesh);
  segment::WallFitOptions options = config.wall_fit_options;
  options.rings = kUnsmoothedFitRings;
  result.mesh = segment::fit_to_wall(unsmoothed_image(input, result, buffers), result.mesh,
                                     result.balloon_stats, options, config.balloon.threads);
  keep_volume(result.mesh, reconstruct::enclosed_volume_ml(result.mesh), fitted_ml);
}

std::optional<reconstruct::SurfaceResult> resurfaced(const volume::Volume& input,
                                                     const segment::Mesh& surface, int genus,
                                                     const Vec3f& seed_mm,
                                                     const PipelineConfig& config,
                                                     bool coarser_when_thick) {
  const mesh::PointCloud samples = mesh::oriented_samples(surface);
  // (Configured cells, not the voxel's, are the user's: 1.25 times them, as the first
  // reconstruction keeps them too.)
  const float coarse =
      coarser_when_thick && config.cell_from_voxel
          ? std::max(kCoarseCells, thick_cell_scale(surface, input.spacing_mm().minCoeff()))
          : kCoarseCells;
  for (const float scale : {coarse, 1.0f}) {
    reconstruct::PoissonOptions scaled = poisson_options(config, input);
    scaled.cell_mm *= scale;
    reconstruct::SurfaceResult s = reconstruct::reconstruct_surface(samples, seed_mm, scaled);
    if (s.mesh.triangles.empty() || !s.seed_enclosed || !s.topology.manifold ||
        s.topology.components != 1 || s.topology.genus != genus)
      continue;
    return s;
  }
  return std::nullopt;
}

void resurface_stage(const volume::Volume& input, const Vec3f& seed_mm,
                     const PipelineConfig& config, PipelineResult& result) {
  if (!config.resurface || !result.topology.manifold || result.topology.components != 1) return;
  const auto t = Clock::now();
  std::optional<reconstruct::SurfaceResult> again =
      resurfaced(input, result.mesh, result.topology.genus, seed_mm, config, true);
  if (again) {
    // (The reconstruction's blur of the indicator takes a curved wall in, where the fits put it.)
    keep_volume(again->mesh, again->topology.volume_ml, result.enclosed_volume_ml);
    result.mesh = std::move(again->mesh);
    result.topology = again->topology;
    result.topology.volume_ml = reconstruct::enclosed_volume_ml(result.mesh);
    result.enclosed_volume_ml = result.topology.volume_ml;
    result.resurfaced = true;
  }
  result.timings.resurface_ms += ms_since(t);
}

}  // namespace sonomesh::daemon::internal
