// The quality verdict on a pipeline result (DESIGN.md "Targets, polarity and the quality verdict").
#include <algorithm>
#include <cmath>

#include "daemon/internal/target_image.h"

namespace sonomesh::daemon::internal {
namespace {

using volume::Vec3i;

// A balloon whose vertices stopped, in the median, within this many voxels of the seed stalled on
// the texture around it (real echo at a one-voxel pre-filter: median 4.8 voxels from a start of
// 2, 0.28 mL in a ~50 mL cavity); the simulator's targets at 64³ reach 10 voxels and more.
constexpr float kStalledRadiusVox = 6.0f;
// Fewer voxels than a ball of 6 voxels' radius: no target a clinician would seed in this volume.
constexpr double kSmallestVoxels = 905.0;
// Share of the final surface's vertices allowed on the volume's edge or the sector's before the
// surface counts as touching it (a few vertices graze it on a target that fills the view).
constexpr double kTouchFraction = 0.01;

double median_distance_mm(const std::vector<Vec3f>& points, const Vec3f& from) {
  if (points.empty()) return 0.0;
  std::vector<float> d;
  d.reserve(points.size());
  for (const Vec3f& p : points) d.push_back((p - from).norm());
  const auto mid = d.begin() + static_cast<std::ptrdiff_t>(d.size() / 2);
  std::nth_element(d.begin(), mid, d.end());
  return *mid;
}

// Vertices within a voxel of the voxel-centre box (no data beyond it).
std::size_t on_volume_edge(const volume::Volume& input, const std::vector<Vec3f>& points) {
  const Vec3f lo = input.min_mm() + input.spacing_mm(), hi = input.max_mm() - input.spacing_mm();
  return static_cast<std::size_t>(std::count_if(points.begin(), points.end(), [&](const Vec3f& p) {
    return (p.array() < lo.array()).any() || (p.array() > hi.array()).any();
  }));
}

// Vertices with a no-data voxel within two voxels (the balloon stops about one voxel inside the
// filled wall's edge after smoothing).
std::size_t on_sector_edge(const volume::Volume& input, const std::vector<std::uint8_t>& no_data,
                           const std::vector<Vec3f>& points) {
  if (no_data.empty()) return 0;
  std::size_t n = 0;
  for (const Vec3f& p : points) {
    const Vec3i c = input.mm_to_index(p).array().round().cast<int>();
    bool near = false;
    for (int dk = -2; dk <= 2 && !near; ++dk)
      for (int dj = -2; dj <= 2 && !near; ++dj)
        for (int di = -2; di <= 2 && !near; ++di) {
          const Vec3i q = c + Vec3i(di, dj, dk);
          near = input.contains_index(q) && no_data[input.linear_index(q.x(), q.y(), q.z())];
        }
    n += near ? 1 : 0;
  }
  return n;
}

}  // namespace

void quality_verdict(const volume::Volume& input, const std::vector<std::uint8_t>& no_data,
                     const Vec3f& seed_mm, PipelineResult& result) {
  std::vector<std::string>& why = result.quality_reasons;
  why.clear();
  const float vox_mm = input.spacing_mm().minCoeff();
  if (result.balloon_stats.leaked) why.emplace_back("leak bound");
  if (!result.balloon.vertices.empty() &&
      median_distance_mm(result.balloon.vertices, seed_mm) < kStalledRadiusVox * vox_mm)
    why.emplace_back("stalled near the seed");
  const std::size_t balloon_n = result.balloon.vertices.size();
  if (balloon_n > 0 && result.stop_counts.iteration_limit > static_cast<int>(0.005 * balloon_n) &&
      result.stop_counts.iteration_limit > 0)
    why.emplace_back("iteration limit");
  if (result.ok) {
    const double voxel_ml = input.spacing_mm().prod() * 1e-3;
    if (result.enclosed_volume_ml < kSmallestVoxels * voxel_ml)
      why.emplace_back("implausibly small");
    const auto& points = result.mesh.vertices;
    const double limit = kTouchFraction * static_cast<double>(points.size());
    if (static_cast<double>(on_volume_edge(input, points)) > limit)
      why.emplace_back("touches the volume edge");
    if (static_cast<double>(on_sector_edge(input, no_data, points)) > limit)
      why.emplace_back("touches the sector edge");
    if (result.topology.components != 1 || !result.topology.watertight)
      why.emplace_back("not one closed surface");
  } else if (why.empty()) {
    why.emplace_back("failed");
  }
  result.quality_ok = why.empty();
}

}  // namespace sonomesh::daemon::internal
