// A surface made again from its own samples (stages.h, resurfaced): the wall fit's vertices
// through Kazhdan's reconstruction once more.
#include <chrono>
#include <optional>
#include <utility>
#include <vector>

#include "daemon/internal/stages.h"

namespace sonomesh::daemon::internal {
namespace {

// `surface` moved along its normals by the one distance that makes it enclose `volume_ml`: the
// reconstruction's blur of the indicator takes a curved wall in by a fraction of a voxel (a
// 64³ echo torus's by 0.2 voxel, 6 % of its volume), and the wall fit had placed that volume.
void keep_volume(segment::Mesh& surface, double volume_ml) {
  const double area_mm2 = mesh::surface_area_mm2(surface);
  if (!(area_mm2 > 0.0)) return;
  const auto out_mm =
      static_cast<float>((volume_ml - reconstruct::enclosed_volume_ml(surface)) * 1e3 / area_mm2);
  const std::vector<Vec3f> normal = mesh::vertex_normals(surface);
  for (std::size_t v = 0; v < normal.size(); ++v) surface.vertices[v] += out_mm * normal[v];
}

}  // namespace

std::optional<reconstruct::SurfaceResult> resurfaced(const volume::Volume& input,
                                                     const segment::Mesh& surface, int genus,
                                                     const Vec3f& seed_mm,
                                                     const PipelineConfig& config,
                                                     float first_cells) {
  const mesh::PointCloud samples = mesh::oriented_samples(surface);
  std::vector<float> scales{first_cells};
  if (first_cells != 1.0f) scales.push_back(1.0f);
  for (const float scale : scales) {
    reconstruct::PoissonOptions scaled = poisson_options(config, input);
    scaled.cell_mm *= scale;
    reconstruct::SurfaceResult s = reconstruct::reconstruct_surface(samples, seed_mm, scaled);
    if (s.mesh.triangles.empty() || !s.seed_enclosed || !s.topology.manifold ||
        s.topology.components != 1 || s.topology.genus != genus)
      continue;
    s.topology.volume_ml = reconstruct::enclosed_volume_ml(s.mesh);
    return s;
  }
  return std::nullopt;
}

void resurface_stage(const volume::Volume& input, const Vec3f& seed_mm,
                     const PipelineConfig& config, PipelineResult& result) {
  if (!config.resurface || !result.topology.manifold || result.topology.components != 1) return;
  const auto t = Clock::now();
  std::optional<reconstruct::SurfaceResult> again =
      resurfaced(input, result.mesh, result.topology.genus, seed_mm, config, 1.0f);
  if (again) {
    keep_volume(again->mesh, result.enclosed_volume_ml);
    result.mesh = std::move(again->mesh);
    result.topology = again->topology;
    result.topology.volume_ml = reconstruct::enclosed_volume_ml(result.mesh);
    result.enclosed_volume_ml = result.topology.volume_ml;
    result.resurfaced = true;
  }
  result.timings.reinflate_ms += ms_since(t);
}

}  // namespace sonomesh::daemon::internal
