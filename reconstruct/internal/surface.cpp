// The whole second step: indicator, marching cubes, the component around the seed.

#include <chrono>

#include "reconstruct/reconstruct.h"

namespace sonomesh::reconstruct {

SurfaceResult reconstruct_surface(const PointCloud& samples, const Vec3f& seed_mm,
                                  const PoissonOptions& options) {
  using clock = std::chrono::steady_clock;
  auto ms = [](clock::duration d) { return std::chrono::duration<double, std::milli>(d).count(); };
  if (!seed_mm.allFinite())
    throw std::invalid_argument("reconstruct_surface: seed_mm is not finite");
  SurfaceResult r;
  const auto t0 = clock::now();
  IndicatorGrid grid = poisson_indicator(samples, options);
  const auto t1 = clock::now();
  const Mesh all = marching_cubes(grid.chi, grid.iso);
  r.mesh =
      mesh::component_enclosing(all, seed_mm, &r.seed_enclosed, &r.components_before_selection);
  const auto t2 = clock::now();
  r.topology = analyze_topology(r.mesh);
  r.iso = grid.iso;
  r.cell_mm = grid.cell_mm;
  r.feature_mm = grid.feature_mm;
  r.grid_dims = {grid.chi.dims().x(), grid.chi.dims().y(), grid.chi.dims().z()};
  r.indicator = std::move(grid.chi);
  r.reconstruct_ms = ms(t1 - t0);
  r.mesh_ms = ms(t2 - t1);
  return r;
}

}  // namespace sonomesh::reconstruct
