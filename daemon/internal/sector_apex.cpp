// The probe's apex from the sector's no-data region (shadow_gain.h).
#include <Eigen/Dense>
#include <algorithm>
#include <array>
#include <cmath>

#include "daemon/internal/shadow_gain.h"

namespace sonomesh::daemon::internal {
namespace {

using volume::Vec3f;
using volume::Vec3i;
using volume::Volume;

// The apex: the side walls' normals lie within this sine of square to the ray from it (median).
constexpr float kApexResidualSin = 0.15f;
constexpr int kMinWallPoints = 100;
constexpr float kFlatWallSum = 20.0f;  // wall_normal's least sum

struct WallPoint {
  Vec3f p_mm, n;  // a data voxel beside the no-data region; the outward normal
};

// The outward normal at voxel (i, j, k): the sum of the offsets of the no-data voxels within two,
// within a ball (a cube's would lean towards its axes) in index space, where it is square to a
// flat wall; over the spacing, square to it in mm. Zero where no flat wall is: beside one the sum
// is 39 voxels along its normal, beside a speck of data amid the no-data region much less.
// (i, j, k) lies two or more voxels from the volume's faces.
Vec3f wall_normal(const Volume& input, const std::vector<std::uint8_t>& no_data, int i, int j,
                  int k) {
  Vec3f n = Vec3f::Zero();
  for (int c = -2; c <= 2; ++c)
    for (int b = -2; b <= 2; ++b)
      for (int a = -2; a <= 2; ++a)
        if (a * a + b * b + c * c <= 6 && no_data[input.linear_index(i + a, j + b, k + c)])
          n += Vec3f(a, b, c);
  if (n.norm() < kFlatWallSum) return Vec3f::Zero();
  return n.cwiseQuotient(input.spacing_mm()).normalized();
}

// A hash of the voxel picks one in four (spatial hashing's primes).
bool one_in_four(int i, int j, int k) {
  const auto u = [](int x) { return static_cast<std::uint32_t>(x); };
  return ((u(i) * 73856093u) ^ (u(j) * 19349663u) ^ (u(k) * 83492791u)) % 4u == 0;
}

// A quarter of the data voxels with a no-data face neighbour, two or more from the volume's faces
// (where the normal's window fits), with their normals. The quarter is picked by a hash of the
// voxel, not by counting: every fourth of a row's two walls would be one wall only.
std::vector<WallPoint> wall_points(const Volume& input, const std::vector<std::uint8_t>& no_data) {
  const Vec3i d = input.dims();
  const std::size_t nx = static_cast<std::size_t>(d.x()), nxy = nx * d.y();
  std::vector<WallPoint> points;
  for (int k = 2; k + 2 < d.z(); ++k)
    for (int j = 2; j + 2 < d.y(); ++j)
      for (int i = 2; i + 2 < d.x(); ++i) {
        const std::size_t at = k * nxy + j * nx + static_cast<std::size_t>(i);
        if (no_data[at] || !(no_data[at - 1] | no_data[at + 1] | no_data[at - nx] |
                             no_data[at + nx] | no_data[at - nxy] | no_data[at + nxy]))
          continue;
        if (!one_in_four(i, j, k)) continue;
        const Vec3f n = wall_normal(input, no_data, i, j, k);
        if (n != Vec3f::Zero()) points.push_back({input.index_to_mm(Vec3f(i, j, k)), n});
      }
  return points;
}

// The beam's rough direction: along the axis whose data grows most from one end to the other
// (the sector widens away from the apex), towards the wider end (every other voxel counted).
Vec3f rough_beam_axis(const Volume& input, const std::vector<std::uint8_t>& no_data) {
  const Vec3i d = input.dims();
  std::array<std::array<double, 2>, 3> ends{};  // per axis: data in its first and last third
  for (int k = 0; k < d.z(); k += 2)
    for (int j = 0; j < d.y(); j += 2)
      for (int i = 0; i < d.x(); i += 2) {
        if (no_data[input.linear_index(i, j, k)]) continue;
        const std::array<int, 3> x{i, j, k};
        for (int a = 0; a < 3; ++a) {
          if (3 * x[a] < d[a]) ends[a][0] += 1.0;
          if (3 * x[a] >= 2 * d[a]) ends[a][1] += 1.0;
        }
      }
  int best = 2;
  double best_ratio = 0.0;
  for (int a = 0; a < 3; ++a) {
    const double lo = std::min(ends[a][0], ends[a][1]) + 1.0;
    const double ratio = std::max(ends[a][0], ends[a][1]) / lo;
    if (ratio > best_ratio) best_ratio = ratio, best = a;
  }
  Vec3f axis = Vec3f::Zero();
  axis[best] = ends[best][1] >= ends[best][0] ? 1.0f : -1.0f;
  return axis;
}

// The point nearest to the planes of the points `side` picks (least squares); nullopt when they
// do not fix a point (fewer than three independent normals).
template <typename Pick>
std::optional<Vec3f> planes_meet(const std::vector<WallPoint>& points, Pick side) {
  Eigen::Matrix3d A = Eigen::Matrix3d::Zero();
  Eigen::Vector3d b = Eigen::Vector3d::Zero();
  int used = 0;
  for (const WallPoint& w : points) {
    if (!side(w)) continue;
    const Eigen::Vector3d n = w.n.cast<double>();
    A += n * n.transpose();
    b += n * n.dot(w.p_mm.cast<double>());
    ++used;
  }
  if (used < kMinWallPoints) return std::nullopt;
  const Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d> eigen(A);
  if (eigen.eigenvalues()(0) < 0.02 * used) return std::nullopt;
  return A.ldlt().solve(b).cast<float>();
}
}  // namespace

// Side walls contain the beams, so their normals are square to the ray from the apex; the far
// arc's normals lie along it. The rough axis picks the first side walls; then each round keeps
// the walls whose normal is within 20° of square to the ray from the last apex.
std::optional<Vec3f> sector_apex_mm(const Volume& input, const std::vector<std::uint8_t>& no_data) {
  if (no_data.empty()) return std::nullopt;
  const std::vector<WallPoint> points = wall_points(input, no_data);
  const Vec3f axis = rough_beam_axis(input, no_data);
  std::optional<Vec3f> apex =
      planes_meet(points, [&](const WallPoint& w) { return std::abs(w.n.dot(axis)) < 0.5f; });
  for (int round = 0; round < 4 && apex; ++round) {
    const Vec3f a = *apex;
    apex = planes_meet(points, [&](const WallPoint& w) {
      const Vec3f ray = w.p_mm - a;
      return std::abs(w.n.dot(ray)) < 0.35f * ray.norm();
    });
  }
  if (!apex) return std::nullopt;
  std::vector<float> residuals;
  for (const WallPoint& w : points) {
    const Vec3f ray = w.p_mm - *apex;
    const float off = std::abs(w.n.dot(ray));
    if (off < 0.35f * ray.norm()) residuals.push_back(off / ray.norm());
  }
  if (quantile(residuals, 0.5f) > kApexResidualSin) return std::nullopt;
  return apex;
}

}  // namespace sonomesh::daemon::internal
