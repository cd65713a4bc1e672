// The last placement of the surface on the wall (segment.h, fit_to_wall): each vertex goes to
// where the image, averaged over the surface around it, crosses half way from the inside's level
// to the wall's (less along a probe's beam).
#include <algorithm>
#include <cmath>
#include <limits>
#include <stdexcept>
#include <utility>
#include <vector>

#include "mesh/parallel.h"
#include "segment/internal/corner_table.h"
#include "segment/internal/image_sampler.h"
#include "segment/internal/step.h"

namespace sonomesh::segment {
namespace {

using namespace internal;

// Vertex -> neighbouring vertices: the vertex after it in each of its triangles, which on a
// closed manifold names every neighbour once (elsewhere a neighbour may be missed or repeated,
// which an average shrugs off).
CornerTable neighbours(const Mesh& surface) {
  return CornerTable(surface, "fit_to_wall",
                     [&](std::uint32_t f, int k) { return surface.triangles[f][(k + 1) % 3]; });
}

// values[v * width + j] replaced by their mean over v and its neighbours, `rounds` times.
void average_over_rings(std::vector<float>& values, int width, const CornerTable& nb, int rounds,
                        mesh::Workers& workers) {
  std::vector<float> next(values.size());
  const std::size_t nv = nb.begin.size() - 1;
  for (int r = 0; r < rounds; ++r) {
    workers.parallel_for(nv, kLightGrain, [&](std::size_t b, std::size_t e) {
      for (std::size_t v = b; v < e; ++v) {
        float* out = &next[v * width];
        std::copy_n(&values[v * width], width, out);
        for (std::uint32_t i = nb.begin[v]; i < nb.begin[v + 1]; ++i) {
          const float* in = &values[std::size_t{nb.list[i]} * width];
          for (int j = 0; j < width; ++j) out[j] += in[j];
        }
        const float scale = 1.0f / static_cast<float>(1 + nb.begin[v + 1] - nb.begin[v]);
        for (int j = 0; j < width; ++j) out[j] *= scale;
      }
    });
    values.swap(next);
  }
}

// Where the averaged profile (samples at (j - centre) · step) crosses `fraction` of the way from
// its lowest level behind the vertex to its highest ahead, nearest the vertex; 0 where it rises
// less than `min_rise` (no wall: a dropout, a seal) or nowhere crosses.
float crossing_offset(const float* profile, int width, float step, float min_rise, float fraction) {
  const int centre = width / 2;
  const float lo = *std::min_element(profile, profile + centre + 1);
  const float hi = *std::max_element(profile + centre, profile + width);
  if (!(hi - lo >= min_rise)) return 0.0f;
  const float mid = lo + fraction * (hi - lo);
  float best = 0.0f, best_abs = std::numeric_limits<float>::max();
  for (int j = 0; j + 1 < width; ++j) {
    if (!(profile[j] < mid && profile[j + 1] >= mid)) continue;
    const float f = (mid - profile[j]) / (profile[j + 1] - profile[j]);
    const float t = (static_cast<float>(j - centre) + f) * step;
    if (std::abs(t) < best_abs) best = t, best_abs = std::abs(t);
  }
  return best_abs < std::numeric_limits<float>::max() ? best : 0.0f;
}

// How far from the inside's level to the wall's vertex p with normal n crosses: half way, or
// along a probe's beam less (WallFitOptions::probe_apex_mm).
float crossing_fraction(const WallFitOptions& o, const Vec3f& p, const Vec3f& n) {
  return !o.probe_apex_mm || faces_probe(p, n, *o.probe_apex_mm) ? 0.5f : o.along_beam_fraction;
}

// Each vertex's image along its normal, `width` samples `step_mm` apart centred on the vertex
// (clamped into the volume).
std::vector<float> sample_profiles(const ImageSampler& sampler, const volume::Volume& smoothed,
                                   const Mesh& surface, const std::vector<Vec3f>& normal, int width,
                                   float step_mm, mesh::Workers& workers) {
  const Vec3f lo_mm = smoothed.min_mm(), hi_mm = smoothed.max_mm();
  const int half = width / 2;
  std::vector<float> profiles(surface.vertices.size() * width);
  workers.parallel_for(surface.vertices.size(), kHeavyGrain, [&](std::size_t b, std::size_t e) {
    for (std::size_t v = b; v < e; ++v)
      for (int j = 0; j < width; ++j) {
        const Vec3f p = surface.vertices[v] + static_cast<float>(j - half) * step_mm * normal[v];
        profiles[v * width + j] = sampler.value(p.cwiseMax(lo_mm).cwiseMin(hi_mm));
      }
  });
  return profiles;
}

void check_input(const volume::Volume& smoothed, const BalloonStats& first_pass,
                 const WallFitOptions& o) {
  if (smoothed.empty()) throw std::invalid_argument("fit_to_wall: empty volume");
  if (!(first_pass.tissue_level > first_pass.seed_level))
    throw std::invalid_argument("fit_to_wall: first_pass holds no seed statistics");
  if (!(o.step_vox > 0.0f) || !(o.reach_vox >= o.step_vox) || o.rings < 0 ||
      !(o.max_move_vox >= 0.0f) || !(o.min_rise_fraction >= 0.0f) ||
      !(o.along_beam_fraction > 0.0f && o.along_beam_fraction < 1.0f))
    throw std::invalid_argument(
        "fit_to_wall: need step_vox > 0, reach_vox >= step_vox, rings >= 0, max_move_vox >= 0, "
        "min_rise_fraction >= 0 and along_beam_fraction in (0, 1)");
}

}  // namespace

Mesh fit_to_wall(const volume::Volume& smoothed_in, const Mesh& surface,
                 const BalloonStats& first_pass, const WallFitOptions& options, int threads) {
  check_input(smoothed_in, first_pass, options);
  volume::Volume converted;
  const volume::Volume& smoothed = as_float32(smoothed_in, converted);
  const float vox_mm = smoothed.spacing_mm().minCoeff();
  const int width = 2 * static_cast<int>(std::lround(options.reach_vox / options.step_vox)) + 1;
  const float step_mm = options.step_vox * vox_mm;
  const CornerTable nb = neighbours(surface);
  const std::vector<Vec3f> normal = mesh::vertex_normals(surface);  // equation (2)'s, as the passes
  mesh::Workers workers(threads);
  std::vector<float> profiles =
      sample_profiles(ImageSampler(smoothed), smoothed, surface, normal, width, step_mm, workers);
  average_over_rings(profiles, width, nb, options.rings, workers);
  const float min_rise =
      options.min_rise_fraction * (first_pass.tissue_level - first_pass.seed_level);
  const std::size_t nv = surface.vertices.size();
  std::vector<float> offset(nv);
  for (std::size_t v = 0; v < nv; ++v)
    offset[v] = crossing_offset(&profiles[v * width], width, step_mm, min_rise,
                                crossing_fraction(options, surface.vertices[v], normal[v]));
  average_over_rings(offset, 1, nb, 1, workers);
  Mesh fitted = surface;
  const float max_mm = options.max_move_vox * vox_mm;
  for (std::size_t v = 0; v < nv; ++v)
    fitted.vertices[v] += std::clamp(offset[v], -max_mm, max_mm) * normal[v];
  return fitted;
}

}  // namespace sonomesh::segment
