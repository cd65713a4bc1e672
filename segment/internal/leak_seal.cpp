// Sealing a leak: which of the kept balloon's moving vertices the leaked surface grew out of.
#include "segment/internal/leak_seal.h"

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <numeric>
#include <unordered_map>
#include <vector>

namespace sonomesh::segment::internal {
namespace {

// New surface is the leaked balloon's more than this far from the kept one (the kept balloon's
// walls do not move; its edges are under two voxels long).
constexpr float kNewSurfaceVox = 2.0f;
// A cluster credited with fewer new vertices per vertex than this grew like a front moving on,
// not like a leak (a leak ends once the mesh tripled, most of it beyond the gap).
constexpr float kLeastLeakGrowth = 4.0f;
// New surface further than this from every moving vertex is not credited to any.
constexpr float kCreditReachVox = 16.0f;

// Points binned on a cubic lattice over their own bounding box, for nearest-point queries within
// a few cells. The rings are clipped to the box: most of a leak's new surface lies beyond the
// moving vertices, where a search over all cells of its reach would visit hundreds of empty ones.
class PointGrid {
 public:
  PointGrid(const std::vector<Vec3f>& points, const std::vector<std::uint32_t>& ids, float cell_mm)
      : points_(points), cell_mm_(cell_mm) {
    if (ids.empty()) return;
    lo_ = hi_ = cell_of(points_[ids.front()]);
    for (const std::uint32_t i : ids) {
      lo_ = lo_.cwiseMin(cell_of(points_[i]));
      hi_ = hi_.cwiseMax(cell_of(points_[i]));
    }
    dims_ = hi_ - lo_ + Eigen::Vector3i::Ones();
    start_.assign(static_cast<std::size_t>(dims_.prod()) + 1, 0);
    for (const std::uint32_t i : ids) ++start_[bin(cell_of(points_[i])) + 1];
    std::partial_sum(start_.begin(), start_.end(), start_.begin());
    ids_.resize(ids.size());
    std::vector<std::uint32_t> fill(start_.begin(), start_.end() - 1);
    for (const std::uint32_t i : ids) ids_[fill[bin(cell_of(points_[i]))]++] = i;
  }

  // The nearest point within `reach_mm` (kInvalidIndex: none), searching rings of cells; of
  // points at the same distance the first in ring, cell and id order.
  std::uint32_t nearest(const Vec3f& p, float reach_mm) const {
    if (ids_.empty()) return kInvalidIndex;
    const Eigen::Vector3i c = cell_of(p);
    const int rings = static_cast<int>(std::ceil(reach_mm / cell_mm_));
    std::uint32_t best = kInvalidIndex;
    float best2 = reach_mm * reach_mm;
    for (int r = 0; r <= rings; ++r) {
      for_ring(c, r, [&](std::size_t b) {
        for (std::uint32_t k = start_[b]; k < start_[b + 1]; ++k)
          if (const float d2 = (points_[ids_[k]] - p).squaredNorm(); d2 < best2)
            best2 = d2, best = ids_[k];
      });
      // A point in ring r + 1 lies at least r cells away: further rings cannot beat it.
      if (best != kInvalidIndex && static_cast<float>(r) * cell_mm_ >= std::sqrt(best2)) break;
    }
    return best;
  }

 private:
  Eigen::Vector3i cell_of(const Vec3f& p) const {
    return (p / cell_mm_).array().floor().cast<int>();
  }
  std::size_t bin(const Eigen::Vector3i& cell) const {
    const Eigen::Vector3i q = cell - lo_;
    return (static_cast<std::size_t>(q.z()) * dims_.y() + q.y()) * dims_.x() + q.x();
  }
  // visit(bin) for each cell of the shell at Chebyshev distance r from c that lies in the box.
  template <typename F>
  void for_ring(const Eigen::Vector3i& c, int r, F&& visit) const {
    const Eigen::Vector3i from = (c - r * Eigen::Vector3i::Ones()).cwiseMax(lo_);
    const Eigen::Vector3i to = (c + r * Eigen::Vector3i::Ones()).cwiseMin(hi_);
    for (int z = from.z(); z <= to.z(); ++z)
      for (int y = from.y(); y <= to.y(); ++y) {
        if (std::abs(z - c.z()) == r || std::abs(y - c.y()) == r) {
          for (int x = from.x(); x <= to.x(); ++x) visit(bin(Eigen::Vector3i(x, y, z)));
          continue;
        }
        // Off the shell's faces in z and y: only its two x faces.
        for (const int x : {c.x() - r, c.x() + r})
          if (x >= from.x() && x <= to.x()) visit(bin(Eigen::Vector3i(x, y, z)));
      }
  }

  const std::vector<Vec3f>& points_;
  float cell_mm_;
  Eigen::Vector3i lo_ = Eigen::Vector3i::Zero(), hi_ = -Eigen::Vector3i::Ones();
  Eigen::Vector3i dims_ = Eigen::Vector3i::Zero();
  std::vector<std::uint32_t> start_;  // bin b's ids are ids_[start_[b], start_[b + 1])
  std::vector<std::uint32_t> ids_;
};

std::vector<std::uint32_t> moving_vertices(const BalloonEvolution::Snapshot& before) {
  std::vector<std::uint32_t> out;
  for (std::uint32_t v = 0; v < before.states.size(); ++v)
    if (before.states[v].reason == StopReason::Moving) out.push_back(v);
  return out;
}

// New leaked surface credited to each vertex of the kept balloon (only moving ones get any).
std::vector<int> credit_new_surface(const BalloonEvolution::Snapshot& before,
                                    const std::vector<std::uint32_t>& moving_ids,
                                    const std::vector<Vec3f>& leaked_mm, float vox_mm) {
  std::vector<std::uint32_t> all(before.mesh.vertices.size());
  std::iota(all.begin(), all.end(), 0u);
  const PointGrid kept(before.mesh.vertices, all, 2.0f * vox_mm);
  const PointGrid moving(before.mesh.vertices, moving_ids, 4.0f * vox_mm);
  std::vector<int> credit(before.mesh.vertices.size(), 0);
  for (const Vec3f& p : leaked_mm) {
    if (kept.nearest(p, kNewSurfaceVox * vox_mm) != kInvalidIndex) continue;
    if (const std::uint32_t m = moving.nearest(p, kCreditReachVox * vox_mm); m != kInvalidIndex)
      ++credit[m];
  }
  return credit;
}

// Union-find root with path halving.
std::uint32_t root(std::vector<std::uint32_t>& parent, std::uint32_t v) {
  while (parent[v] != v) v = parent[v] = parent[parent[v]];
  return v;
}

// Clusters of moving vertices connected by the kept balloon's edges: each vertex's root.
std::vector<std::uint32_t> moving_clusters(const BalloonEvolution::Snapshot& before) {
  std::vector<std::uint32_t> parent(before.mesh.vertices.size());
  std::iota(parent.begin(), parent.end(), 0u);
  auto moving = [&](std::uint32_t v) { return before.states[v].reason == StopReason::Moving; };
  for (const auto& t : before.mesh.triangles)
    for (int e = 0; e < 3; ++e) {
      const std::uint32_t a = t[e], b = t[(e + 1) % 3];
      if (moving(a) && moving(b)) parent[root(parent, a)] = root(parent, b);
    }
  for (std::uint32_t v = 0; v < parent.size(); ++v) parent[v] = root(parent, v);
  return parent;
}

}  // namespace

std::optional<LeakSeal> seal_leak(const BalloonEvolution::Snapshot& before,
                                  const std::vector<Vec3f>& leaked_mm, float vox_mm) {
  const std::vector<std::uint32_t> moving = moving_vertices(before);
  const std::vector<int> credit = credit_new_surface(before, moving, leaked_mm, vox_mm);
  const std::vector<std::uint32_t> cluster = moving_clusters(before);
  std::unordered_map<std::uint32_t, std::pair<int, int>> grown;  // root: credit, size
  for (const std::uint32_t v : moving) {
    grown[cluster[v]].first += credit[v];
    ++grown[cluster[v]].second;
  }
  std::vector<bool> seal(credit.size(), false);
  bool any = false;
  for (std::uint32_t v = 0; v < credit.size(); ++v) {
    const auto it = grown.find(cluster[v]);
    if (it == grown.end()) continue;
    const auto [credited, size] = it->second;
    seal[v] = credit[v] > 0 &&
              static_cast<float>(credited) >= kLeastLeakGrowth * static_cast<float>(size);
    any = any || seal[v];
  }
  if (!any) return std::nullopt;
  std::vector<bool> ring = seal;  // and the moving vertices next to them
  for (const auto& t : before.mesh.triangles)
    for (int e = 0; e < 3; ++e)
      for (int o = 1; o < 3 && seal[t[e]]; ++o)
        if (before.states[t[(e + o) % 3]].reason == StopReason::Moving) ring[t[(e + o) % 3]] = true;
  LeakSeal out;
  from_plain_mesh(before.mesh, out.start);
  for (std::uint32_t v = 0; v < credit.size(); ++v) {
    VertexState& s = out.start.state(Vertex{v});
    s = before.states[v];
    s.anchor_mm = before.mesh.vertices[v];
    s.marked_voxel = -1;
    if (ring[v]) s.reason = StopReason::Boundary, ++out.sealed;
  }
  return out;
}

}  // namespace sonomesh::segment::internal
