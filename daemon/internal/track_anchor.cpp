// A tracking chain's anchor (track_anchor.h): its own fit, and the affine map to each volume.
#include "daemon/internal/track_anchor.h"

#include <Eigen/Cholesky>
#include <algorithm>
#include <cmath>
#include <utility>

namespace sonomesh::daemon::internal {
namespace {

// The wall fit, repeated while it still moves the surface by this much on average (a breath
// moves a wall up to about a voxel between two volumes at 10 volumes/s; one fit moves a vertex by
// one at most), at most kMostFits times.
constexpr float kSettledVox = 0.25f;
constexpr int kMostFits = 3;
// The map's second fit leaves out the vertices the first leaves further than this from their
// fitted place (a fit that followed a grain, or a wall that deformed beyond what a map follows).
constexpr double kMapOutlierVox = 1.0;
// How strongly the map holds to the last volume's, per vertex and in units of the anchor's mean
// squared extent for the linear part: it decides only what the surface leaves free (a sphere's
// rotation, a cylinder's slide along its axis), where the distances along the normals say nothing.
constexpr double kMapHold = 1e-3;

using Vec12 = Eigen::Matrix<double, 12, 1>;
using Mat12 = Eigen::Matrix<double, 12, 12>;

// The map as 12 numbers: linear − identity row by row, then the shift.
Vec12 map_vector(const PipelineResult::Tracking::Map& map) {
  Vec12 x;
  const Mat3f change = map.linear - Mat3f::Identity();
  for (int j = 0; j < 3; ++j)
    for (int k = 0; k < 3; ++k) x[3 * j + k] = change(j, k);
  x.tail<3>() = map.shift_mm.cast<double>();
  return x;
}

PipelineResult::Tracking::Map as_map(const Vec12& x) {
  PipelineResult::Tracking::Map map;
  for (int j = 0; j < 3; ++j)
    for (int k = 0; k < 3; ++k)
      map.linear(j, k) = static_cast<float>(x[3 * j + k] + (j == k ? 1.0 : 0.0));
  map.shift_mm = x.tail<3>().cast<float>();
  return map;
}

// The anchor's vertices where `map` puts them.
segment::Mesh mapped(const TrackingAnchor& anchor, const PipelineResult::Tracking::Map& map) {
  segment::Mesh m = anchor.surface;
  for (Vec3f& p : m.vertices)
    p = map.linear * (p - anchor.centre_mm) + anchor.centre_mm + map.shift_mm;
  return m;
}

// One least-squares solve of the map: each vertex's distance along its fitted normal from where
// the map puts it to where the fit did, the vertices beyond `outlier_mm` of `x` left out (none
// when it is not positive), held to `held` by kMapHold.
Vec12 solve_map(const TrackingAnchor& anchor, const segment::Mesh& fitted,
                const std::vector<Vec3f>& normal, const Vec12& x, const Vec12& held,
                double outlier_mm) {
  Mat12 h = Mat12::Zero();
  Vec12 g = Vec12::Zero();
  double extent2 = 0.0;
  for (std::size_t v = 0; v < normal.size(); ++v) {
    const Eigen::Vector3d d = (anchor.surface.vertices[v] - anchor.centre_mm).cast<double>();
    const Eigen::Vector3d n = normal[v].cast<double>();
    Vec12 row;
    for (int j = 0; j < 3; ++j)
      for (int k = 0; k < 3; ++k) row[3 * j + k] = n[j] * d[k];
    row.tail<3>() = n;
    const double moved = n.dot((fitted.vertices[v] - anchor.surface.vertices[v]).cast<double>());
    extent2 += d.squaredNorm();
    if (outlier_mm > 0.0 && std::abs(row.dot(x) - moved) > outlier_mm) continue;
    h.selfadjointView<Eigen::Lower>().rankUpdate(row);
    g += row * moved;
  }
  const double count = static_cast<double>(std::max<std::size_t>(1, normal.size()));
  Vec12 hold;
  hold.head<9>().setConstant(kMapHold * extent2);
  hold.tail<3>().setConstant(kMapHold * count);
  h.diagonal() += hold;
  g += hold.cwiseProduct(held);
  return h.selfadjointView<Eigen::Lower>().ldlt().solve(g);
}

}  // namespace

Vec3f vertex_centroid_mm(const segment::Mesh& surface) {
  Vec3f sum = Vec3f::Zero();
  for (const Vec3f& p : surface.vertices) sum += p;
  return surface.vertices.empty() ? sum : Vec3f(sum / static_cast<float>(surface.vertices.size()));
}

segment::Mesh follow_wall(const volume::Volume& smoothed, const segment::Mesh& start,
                          const segment::BalloonStats& levels, const PipelineConfig& config) {
  segment::Mesh fitted = start;
  const double vox_mm = smoothed.spacing_mm().minCoeff();
  for (int i = 0; i < kMostFits; ++i) {
    segment::Mesh next = segment::fit_to_wall(smoothed, fitted, levels, config.wall_fit_options,
                                              config.balloon.threads);
    double moved_mm = 0.0;
    for (std::size_t v = 0; v < next.vertices.size(); ++v)
      moved_mm += (next.vertices[v] - fitted.vertices[v]).norm();
    fitted = std::move(next);
    if (moved_mm < kSettledVox * vox_mm * static_cast<double>(fitted.vertices.size())) break;
  }
  return fitted;
}

std::shared_ptr<const TrackingAnchor> make_anchor(const volume::Volume& smoothed,
                                                  const PipelineResult& result,
                                                  const PipelineConfig& config) {
  if (!(result.balloon_stats.tissue_level > result.balloon_stats.seed_level)) return nullptr;
  auto anchor = std::make_shared<TrackingAnchor>();
  anchor->surface = result.mesh;
  anchor->centre_mm = vertex_centroid_mm(result.mesh);
  const segment::Mesh fitted = follow_wall(smoothed, result.mesh, result.balloon_stats, config);
  const std::vector<Vec3f> normal = mesh::vertex_normals(result.mesh);
  anchor->own_fit_mm.resize(normal.size());
  for (std::size_t v = 0; v < normal.size(); ++v)
    anchor->own_fit_mm[v] = normal[v].dot(fitted.vertices[v] - result.mesh.vertices[v]);
  return anchor;
}

segment::Mesh mapped_anchor(const PipelineResult::Tracking& tracking) {
  return mapped(*tracking.anchor, tracking.map);
}

segment::Mesh predicted_anchor(const PipelineResult::Tracking& tracking) {
  const PipelineResult::Tracking::Map& now = tracking.map;
  const PipelineResult::Tracking::Map& last = tracking.last_map;
  return mapped(*tracking.anchor, {.linear = 2.0f * now.linear - last.linear,
                                   .shift_mm = 2.0f * now.shift_mm - last.shift_mm});
}

void take_off_own_fit(const TrackingAnchor& anchor, const segment::Mesh& start,
                      segment::Mesh& fitted) {
  const std::vector<Vec3f> normal = mesh::vertex_normals(start);
  for (std::size_t v = 0; v < normal.size(); ++v)
    fitted.vertices[v] -= anchor.own_fit_mm[v] * normal[v];
}

void fit_anchor_map(const segment::Mesh& fitted, float vox_mm, PipelineResult::Tracking& tracking) {
  const std::vector<Vec3f> normal = mesh::vertex_normals(fitted);
  const Vec12 held = map_vector(tracking.map);
  const Vec12 first = solve_map(*tracking.anchor, fitted, normal, held, held, 0.0);
  tracking.last_map = tracking.map;
  tracking.map =
      as_map(solve_map(*tracking.anchor, fitted, normal, first, held, kMapOutlierVox * vox_mm));
}

}  // namespace sonomesh::daemon::internal
