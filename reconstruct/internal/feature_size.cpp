// The narrowest feature an oriented point set describes (reconstruct.h): what the FFT grid has
// to resolve so that the reconstruction keeps the topology the samples have.
//
// Why pairs of samples with opposite normals: a gap (the tunnel a needle leaves through a cyst)
// shows as two walls whose outward normals face each other, a thin solid (a torus's tube) as two
// walls back to back. Both vanish under the reconstruction's blur once they are narrower than its
// width. Why both normal cones: a wedge (a needle meeting the cyst wall at an angle) also has
// walls that come arbitrarily close, but only near an edge that no grid resolves and that changes
// no topology; requiring each sample to lie in the other's cone keeps the walls of a pair nearly
// parallel, which a wedge only is when it is almost a slab. Why a minimum area: one or two stray
// pairs (a crease, a spike the curvature stop froze) are not a feature.

#include <algorithm>
#include <cmath>
#include <limits>
#include <numeric>
#include <stdexcept>
#include <string>

#include "mesh/parallel.h"
#include "reconstruct/reconstruct.h"

namespace sonomesh::reconstruct {
namespace {

// tan of the cone half-angle (~26.6°). A sample on a tube with a few samples around it finds a
// partner this close to diametric; wider cones admit steeper wedges.
constexpr float kConeTan = 0.5f;
// A partner's normal must be within 60° of the exact opposite (cheap pre-test; the two cones
// together imply about 53°).
constexpr float kOpposedCos = -0.5f;
// The bucket grid stays small however fine max_width_mm is relative to the cloud: larger buckets
// only cost pair tests, never a missed pair.
constexpr int kMaxBucketsPerAxis = 128;

void check(bool ok, const std::string& what) {
  if (!ok) throw std::invalid_argument("narrowest_feature_mm: " + what);
}

// Samples sorted by bucket, positions and normals copied in that order so that a query reads
// memory front to back.
struct Buckets {
  Vec3f origin_mm;
  float size_mm = 0.0f;
  std::array<int, 3> dims{};
  std::vector<std::uint32_t> start;    // per bucket, into order; one extra entry at the end
  std::vector<std::uint32_t> order;    // sample indices sorted by bucket
  std::vector<Vec3f> points, normals;  // in `order`

  int axis_index(float p_mm, int a) const {
    return std::clamp(int((p_mm - origin_mm[a]) / size_mm), 0, dims[a] - 1);
  }
  std::size_t index(int x, int y, int z) const {
    return std::size_t(x) + std::size_t(dims[0]) * (std::size_t(y) + std::size_t(dims[1]) * z);
  }
};

Buckets make_buckets(const std::vector<Vec3f>& points, const std::vector<Vec3f>& normals,
                     float reach_mm) {
  Vec3f lo = points.front(), hi = lo;
  for (const auto& p : points) {
    lo = lo.cwiseMin(p);
    hi = hi.cwiseMax(p);
  }
  Buckets b;
  b.origin_mm = lo;
  b.size_mm = std::max(reach_mm, (hi - lo).maxCoeff() / float(kMaxBucketsPerAxis));
  for (int a = 0; a < 3; ++a) b.dims[a] = int((hi[a] - lo[a]) / b.size_mm) + 1;
  const std::size_t n_buckets = std::size_t(b.dims[0]) * b.dims[1] * b.dims[2];
  std::vector<std::uint32_t> bucket_of(points.size());
  b.start.assign(n_buckets + 1, 0);
  for (std::size_t i = 0; i < points.size(); ++i) {
    const auto& p = points[i];
    bucket_of[i] = std::uint32_t(
        b.index(b.axis_index(p.x(), 0), b.axis_index(p.y(), 1), b.axis_index(p.z(), 2)));
    ++b.start[bucket_of[i] + 1];
  }
  std::partial_sum(b.start.begin(), b.start.end(), b.start.begin());
  b.order.resize(points.size());
  std::vector<std::uint32_t> fill(b.start.begin(), b.start.end() - 1);
  for (std::size_t i = 0; i < points.size(); ++i) b.order[fill[bucket_of[i]]++] = std::uint32_t(i);
  b.points.resize(points.size());
  b.normals.resize(points.size());
  for (std::size_t q = 0; q < b.order.size(); ++q) {
    b.points[q] = points[b.order[q]];
    b.normals[q] = normals[b.order[q]];
  }
  return b;
}

// Distance along its normal from the q-th bucketed sample to its nearest partner (+infinity if
// none within max_width_mm).
float local_width(const Buckets& b, std::uint32_t q_self, float max_width_mm) {
  const Vec3f& p = b.points[q_self];
  const Vec3f& n = b.normals[q_self];
  const float reach2 = max_width_mm * max_width_mm * (1.0f + kConeTan * kConeTan);
  float best = std::numeric_limits<float>::infinity();
  const int cx = b.axis_index(p.x(), 0), cy = b.axis_index(p.y(), 1), cz = b.axis_index(p.z(), 2);
  for (int z = std::max(cz - 1, 0); z <= std::min(cz + 1, b.dims[2] - 1); ++z)
    for (int y = std::max(cy - 1, 0); y <= std::min(cy + 1, b.dims[1] - 1); ++y)
      for (int x = std::max(cx - 1, 0); x <= std::min(cx + 1, b.dims[0] - 1); ++x) {
        const std::size_t k = b.index(x, y, z);
        for (std::uint32_t q = b.start[k]; q < b.start[k + 1]; ++q) {
          const Vec3f& m = b.normals[q];
          if (q == q_self || n.dot(m) > kOpposedCos) continue;
          const Vec3f d = b.points[q] - p;
          if (d.squaredNorm() > reach2) continue;
          // Gap: j ahead of i and facing back (d·n > 0, d·m < 0). Solid: j behind, both turned
          // away from each other (d·n < 0, d·m > 0).
          const float along_i = d.dot(n), along_j = -d.dot(m);
          if (along_i == 0.0f || (along_i > 0.0f) != (along_j > 0.0f)) continue;
          const float t = std::abs(along_i);
          if (t >= best || t > max_width_mm) continue;
          if ((d - along_i * n).squaredNorm() > kConeTan * kConeTan * t * t) continue;
          if ((d + along_j * m).squaredNorm() > kConeTan * kConeTan * along_j * along_j) continue;
          best = t;
        }
      }
  return best;
}

}  // namespace

float narrowest_feature_mm(const PointCloud& s, float max_width_mm, float min_area_mm2) {
  check(s.normals.size() == s.points.size(), "normals.size() != points.size()");
  check(s.area_mm2.size() == s.points.size(), "area_mm2.size() != points.size()");
  check(std::isfinite(max_width_mm) && max_width_mm > 0.0f, "max_width_mm must be positive");
  check(std::isfinite(min_area_mm2) && min_area_mm2 >= 0.0f,
        "min_area_mm2 must be finite and >= 0");
  const float none = std::numeric_limits<float>::infinity();
  if (s.points.size() < 2) return none;
  for (std::size_t n = 0; n < s.points.size(); ++n)
    check(s.points[n].allFinite() && s.normals[n].allFinite() && std::isfinite(s.area_mm2[n]),
          "sample " + std::to_string(n) + " is not finite");

  const Buckets b =
      make_buckets(s.points, s.normals, max_width_mm * std::sqrt(1.0f + kConeTan * kConeTan));
  std::vector<float> width(s.points.size());
  const int n = int(s.points.size());
  mesh::parallel_chunks(0, n, mesh::default_threads(), [&](int q0, int q1, int) {
    for (int q = q0; q < q1; ++q)
      width[b.order[q]] = local_width(b, std::uint32_t(q), max_width_mm);
  });

  std::vector<std::uint32_t> thin;
  for (std::uint32_t i = 0; i < std::uint32_t(n); ++i)
    if (width[i] <= max_width_mm) thin.push_back(i);
  std::sort(thin.begin(), thin.end(), [&](auto a, auto c) { return width[a] < width[c]; });
  double area_mm2 = 0.0;
  for (std::uint32_t i : thin) {
    area_mm2 += s.area_mm2[i];
    if (area_mm2 >= min_area_mm2) return width[i];
  }
  return none;
}

}  // namespace sonomesh::reconstruct
