// The fitted surface's last steps (stages.h): the fit once more on the unsmoothed image at the
// fitted volume (fit_unsmoothed), and the surface made again from its own samples (resurfaced),
// the wall fit's vertices through Kazhdan's reconstruction once more.
#include <algorithm>
#include <chrono>
#include <cmath>
#include <numeric>
#include <optional>
#include <utility>
#include <vector>

#include "daemon/internal/bright_inside.h"
#include "daemon/internal/stages.h"
#include "daemon/internal/target_image.h"

namespace sonomesh::daemon::internal {
namespace {

// First on cells this many times the configured ones (half the cells, and the coarser grid
// averages more of the speckle away), or a thick target's coarser ones, then on the configured
// ones where that lost the genus (a 2-voxel needle's tunnel may close; at 1.5 times for every
// target thin tubes were lost too: docs/stopping.md item 19).
constexpr float kCoarseCells = 1.25f;

// The area of the vertices not held: each one's third of its triangles' (mesh::oriented_samples).
double moving_area_mm2(const segment::Mesh& surface, const std::vector<char>& held) {
  if (held.empty()) return mesh::surface_area_mm2(surface);
  const mesh::PointCloud moving =
      mesh::oriented_samples(surface, std::vector<char>(surface.triangles.size(), 1), held);
  return std::accumulate(moving.area_mm2.begin(), moving.area_mm2.end(), 0.0);
}

// Over more rings than the fit on the smoothed image: the unsmoothed image's speckle is finer.
constexpr int kUnsmoothedFitRings = 5;

std::vector<char> facing_the_probe(const segment::Mesh& surface, const Vec3f& apex_mm) {
  const std::vector<Vec3f> normal = mesh::vertex_normals(surface);
  std::vector<char> facing(normal.size(), 0);
  for (std::size_t v = 0; v < normal.size(); ++v)
    facing[v] = segment::faces_probe(surface.vertices[v], normal[v], apex_mm) ? 1 : 0;
  return facing;
}

// The fitted surface has no tunnel: where it passed over a bright structure across the target,
// the structure's walls join the surface's samples and the surface is made again, then fitted
// to the wall. The first reconstruction's test (open_bright_inside) can miss a thin needle that
// the opened balloon wrapped half-way (a 64³ cyst's, 2.5 voxels across: 47 bright voxels inside
// its χ, none of them deep), which the fitted surface covers whole. Without a probe sector there
// is no shadow to say a needle is there, so the structure must then hold half the bright voxels
// inside (bright_structure). A surface made again without the tunnel is not kept, and the
// verdict says "bright structure inside".
void open_needle_passed_over(const volume::Volume& input, const volume::Volume& smoothed,
                             const Vec3f& seed_mm, const PipelineConfig& config,
                             PipelineResult& result) {
  if (result.topology.genus != 0 || result.bright_inside_left) return;
  const volume::Volume labels = reconstruct::rasterize_labels(result.mesh, input);
  const InsideRegion region =
      inside_labels(labels, mesh::bounding_box(result.mesh), result.balloon_stats);
  std::optional<reconstruct::SurfaceResult> s =
      with_bright_walls(smoothed, region, mesh::oriented_samples(result.mesh), seed_mm,
                        poisson_options(config, input), result.shadow_voxels > 0);
  if (!s) return;
  result.bright_inside_opened = true;
  if (s->mesh.triangles.empty() || !s->seed_enclosed || !s->topology.manifold ||
      s->topology.components != 1 || s->topology.genus == 0) {
    result.bright_inside_left = true;
    return;
  }
  // (On the voxel's cells the needle's walls blur the tunnel wide: the wall fit takes it back.)
  result.mesh = segment::fit_to_wall(smoothed, s->mesh, result.balloon_stats,
                                     config.wall_fit_options, config.balloon.threads);
  result.topology = s->topology;
  result.topology.volume_ml = reconstruct::enclosed_volume_ml(result.mesh);
  result.enclosed_volume_ml = result.topology.volume_ml;
}

}  // namespace

void keep_volume(segment::Mesh& surface, double has_ml, double volume_ml,
                 const std::vector<char>& held) {
  const double area_mm2 = moving_area_mm2(surface, held);
  if (!(area_mm2 > 0.0)) return;
  const auto out_mm = static_cast<float>((volume_ml - has_ml) * 1e3 / area_mm2);
  const std::vector<Vec3f> normal = mesh::vertex_normals(surface);
  for (std::size_t v = 0; v < normal.size(); ++v)
    if (held.empty() || !held[v]) surface.vertices[v] += out_mm * normal[v];
}

void fit_unsmoothed(const volume::Volume& input, PipelineBuffers& buffers,
                    const PipelineConfig& config, PipelineResult& result) {
  const double fitted_ml = reconstruct::enclosed_volume_ml(result.mesh);
  const segment::BalloonStats& levels = result.balloon_stats;
  result.fitted_wall_support =
      wall_support(buffers.smoothed, result.mesh, levels.seed_level, levels.tissue_level);
  segment::WallFitOptions options = config.wall_fit_options;
  options.rings = kUnsmoothedFitRings;
  segment::Mesh fitted = segment::fit_to_wall(unsmoothed_image(input, result, buffers), result.mesh,
                                              levels, options, config.balloon.threads);
  // Where the probe faces the wall, the pre-filter spread the wall's specular echo inward and the
  // smoothed crossing lies half a voxel inside: those vertices keep the unsmoothed crossing. The
  // others keep its shape at the volume the smoothed fit gave them.
  const std::optional<Vec3f>& apex_mm = buffers.no_data.apex_mm;
  const std::vector<char> facing =
      apex_mm ? facing_the_probe(result.mesh, *apex_mm) : std::vector<char>{};
  for (std::size_t v = 0; v < facing.size(); ++v)  // (`fitted` as if the facing had not moved)
    if (facing[v]) std::swap(fitted.vertices[v], result.mesh.vertices[v]);
  keep_volume(fitted, reconstruct::enclosed_volume_ml(fitted), fitted_ml, facing);
  for (std::size_t v = 0; v < facing.size(); ++v)
    if (facing[v]) fitted.vertices[v] = result.mesh.vertices[v];
  result.mesh = std::move(fitted);
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

void resurface_stage(const volume::Volume& input, const volume::Volume& smoothed,
                     const Vec3f& seed_mm, const PipelineConfig& config, PipelineResult& result) {
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
  open_needle_passed_over(input, smoothed, seed_mm, config, result);
  result.timings.resurface_ms += ms_since(t);
}

}  // namespace sonomesh::daemon::internal
