// The bright voxels of the shadow search and their clusters (bright_mask.h).
#include "daemon/internal/bright_mask.h"

#include <algorithm>

#include "mesh/parallel.h"

namespace sonomesh::daemon::internal {

using volume::Vec3i;

Vec3i index_of(const Vec3i& dims, std::size_t voxel) {
  const auto nx = static_cast<std::size_t>(dims.x()), ny = static_cast<std::size_t>(dims.y());
  return Vec3i(static_cast<int>(voxel % nx), static_cast<int>(voxel / nx % ny),
               static_cast<int>(voxel / (nx * ny)));
}

BrightMask::BrightMask(const volume::Volume& image, float level)
    : v_(image.f32()),
      d_(image.dims()),
      nx_(d_.x()),
      nxy_(nx_ * d_.y()),
      level_(level),
      mark_(v_.size(), kUntested) {}

bool BrightMask::cross_over(std::ptrdiff_t at) const {
  if (v_[at] <= level_) return false;
  const float sum = v_[at] + v_[at - 1] + v_[at + 1] + v_[at - nx_] + v_[at + nx_] + v_[at - nxy_] +
                    v_[at + nxy_];
  return sum > 7.0f * level_;
}

bool BrightMask::test(std::size_t voxel) const {
  const Vec3i x = index_of(d_, voxel);
  if ((x.array() < 1).any() || (x.array() > d_.array() - 2).any()) return false;
  return cross_over(static_cast<std::ptrdiff_t>(voxel));
}

void BrightMask::scan(const IndexBox& box, int threads, std::vector<std::size_t>& ones) {
  const Vec3i lo = box.lo.cwiseMax(Vec3i::Ones()), hi = box.hi.cwiseMin(d_ - Vec3i::Constant(2));
  // (The whole volume scanned, an untested mark is a dark voxel: no need to write it.)
  all_scanned_ = all_scanned_ || (lo == Vec3i::Ones() && hi == d_ - Vec3i::Constant(2));
  const std::uint8_t dark = all_scanned_ ? kUntested : kDark;
  std::vector<std::vector<std::size_t>> found(static_cast<std::size_t>(threads));
  mesh::parallel_chunks(lo.z(), hi.z() + 1, threads, [&](int k0, int k1, int c) {
    for (int k = k0; k < k1; ++k)
      for (int j = lo.y(); j <= hi.y(); ++j)
        for (int i = lo.x(); i <= hi.x(); ++i) {
          const std::ptrdiff_t at = k * nxy_ + j * nx_ + i;
          mark_[at] = cross_over(at) ? kBright : dark;
          if (mark_[at] == kBright) found[c].push_back(static_cast<std::size_t>(at));
        }
  });
  ones.clear();
  for (const std::vector<std::size_t>& chunk : found)
    ones.insert(ones.end(), chunk.begin(), chunk.end());
}

bool BrightMask::bright(std::size_t voxel) const {
  const std::uint8_t m = mark_[voxel];
  return m == kUntested ? !all_scanned_ && test(voxel) : m != kDark;
}

void BrightMask::take_cluster(std::size_t start, std::vector<std::size_t>& cluster) {
  flood(start, kBright, kTaken, cluster);
  // The order a scan of the whole volume takes it in, from its first voxel in linear order: the
  // casting test reads a sample of the cluster in this order.
  if (const std::size_t first = *std::min_element(cluster.begin(), cluster.end()); first != start) {
    flood(first, kTaken, kReordered, cluster);
    for (const std::size_t v : cluster) mark_[v] = kTaken;
  }
}

void BrightMask::flood(std::size_t start, std::uint8_t from, std::uint8_t to,
                       std::vector<std::size_t>& cluster) {
  const auto nx = static_cast<std::size_t>(nx_), nxy = static_cast<std::size_t>(nxy_);
  cluster.assign(1, start);
  mark_[start] = to;
  for (std::size_t next = 0; next < cluster.size(); ++next) {
    const std::size_t at = cluster[next];
    // (In range: the volume's faces hold no bright voxel.)
    for (const std::size_t n : {at - 1, at + 1, at - nx, at + nx, at - nxy, at + nxy}) {
      if (mark_[n] == kUntested && !all_scanned_) mark_[n] = test(n) ? kBright : kDark;
      if (mark_[n] != from) continue;
      mark_[n] = to;
      cluster.push_back(n);
    }
  }
}

}  // namespace sonomesh::daemon::internal
