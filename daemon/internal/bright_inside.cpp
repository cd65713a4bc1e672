// Bright structure inside a surface (bright_inside.h).
#include "daemon/internal/bright_inside.h"

#include <algorithm>
#include <array>
#include <cmath>
#include <numeric>
#include <optional>
#include <random>
#include <utility>
#include <vector>

#include "daemon/internal/clock.h"

namespace sonomesh::daemon::internal {
namespace {

constexpr int kDeepVox = 2;
// Deep voxels a structure has beyond the odd bright grain: a needle through a 96³ cyst has ~270.
constexpr long kLeastDeepVox = 40;

const std::array<Vec3i, 6> kFaces = {Vec3i(1, 0, 0),  Vec3i(-1, 0, 0), Vec3i(0, 1, 0),
                                     Vec3i(0, -1, 0), Vec3i(0, 0, 1),  Vec3i(0, 0, -1)};

float mid_level(const segment::BalloonStats& levels) {
  return 0.5f * (levels.seed_level + levels.tissue_level);
}

// The box in `grid`'s voxel indices, clamped to it.
void index_box(const volume::Volume& grid, const mesh::Box& box, InsideRegion& region) {
  const Vec3i last = grid.dims() - Vec3i::Ones();
  region.lo = grid.mm_to_index(box.lo_mm).array().floor().cast<int>().max(0).matrix();
  region.hi = grid.mm_to_index(box.hi_mm).array().ceil().cast<int>().min(last.array()).matrix();
}

// Calls visit(v) for every voxel of the region's box that is inside and brighter than the mid
// level.
template <typename Visit>
void for_bright_inside(const volume::Volume& smoothed, const InsideRegion& region, Visit visit) {
  const auto& image = smoothed.f32();
  for (int z = region.lo.z(); z <= region.hi.z(); ++z)
    for (int y = region.lo.y(); y <= region.hi.y(); ++y)
      for (int x = region.lo.x(); x <= region.hi.x(); ++x) {
        const Vec3i v(x, y, z);
        if (image[smoothed.linear_index(x, y, z)] > region.mid_level && region.inside(v)) visit(v);
      }
}

float value(const volume::Volume& smoothed, const Vec3i& v) {
  return smoothed.f32()[smoothed.linear_index(v.x(), v.y(), v.z())];
}

// The smoothed image's gradient at p, by central differences half a voxel either way.
Vec3f gradient_at(const volume::Volume& smoothed, const Vec3f& p_mm) {
  Vec3f g;
  for (int a = 0; a < 3; ++a) {
    Vec3f d = Vec3f::Zero();
    d[a] = 0.5f * smoothed.spacing_mm()[a];
    g[a] = volume::sample_mm(smoothed, p_mm + d) - volume::sample_mm(smoothed, p_mm - d);
  }
  return g;
}

bool deep_inside(const volume::Volume& smoothed, const InsideRegion& region, const Vec3i& v) {
  for (int a = 0; a < 3; ++a)
    for (const int sign : {-1, 1}) {
      Vec3i q = v;
      q[a] += sign * kDeepVox;
      if (!smoothed.contains_index(q) || !region.inside(q)) return false;
    }
  return true;
}

// Voxel v's place in a vector over the region's box.
std::size_t box_index(const InsideRegion& region, const Vec3i& v) {
  const Vec3i n = region.hi - region.lo + Vec3i::Ones();
  const Vec3i r = v - region.lo;
  return (std::size_t(r.z()) * n.y() + r.y()) * n.x() + r.x();
}

// The bright voxels inside, labelled by 26-connected component on the region's box (label: -1
// none, else the component's number), with each component's voxel and deep voxel counts.
struct Components {
  std::vector<int> label;
  std::vector<long> size, deep;
};

Components label_components(const volume::Volume& smoothed, const InsideRegion& region) {
  Components out;
  const Vec3i n = region.hi - region.lo + Vec3i::Ones();
  if ((n.array() <= 0).any()) return out;  // (a surface outside the grid: no box)
  std::vector<int>& label = out.label;
  label.assign(std::size_t(n.prod()), -2);  // -2: not bright inside
  std::vector<Vec3i> bright;                // (the inside test samples χ: once per voxel)
  for_bright_inside(smoothed, region, [&](const Vec3i& v) {
    label[box_index(region, v)] = -3;  // bright, not labelled yet
    bright.push_back(v);
  });
  std::vector<Vec3i> stack;
  for (const Vec3i& start : bright) {
    if (label[box_index(region, start)] != -3) continue;
    const int c = static_cast<int>(out.size.size());
    out.size.push_back(0);
    out.deep.push_back(0);
    label[box_index(region, start)] = c;
    stack.assign(1, start);
    while (!stack.empty()) {
      const Vec3i v = stack.back();
      stack.pop_back();
      ++out.size[c];
      out.deep[c] += deep_inside(smoothed, region, v) ? 1 : 0;
      for (int dz = -1; dz <= 1; ++dz)
        for (int dy = -1; dy <= 1; ++dy)
          for (int dx = -1; dx <= 1; ++dx) {
            const Vec3i q = v + Vec3i(dx, dy, dz);
            if ((q.array() < region.lo.array()).any() || (q.array() > region.hi.array()).any() ||
                label[box_index(region, q)] != -3)
              continue;
            label[box_index(region, q)] = c;
            stack.push_back(q);
          }
    }
  }
  for (int& l : label) l = l >= 0 ? l : -1;
  return out;
}

// Component `c` as a structure.
BrightStructure component(const InsideRegion& region, const Components& components, int c) {
  BrightStructure s;
  s.deep_vox = components.deep[c];
  Vec3i lo = region.hi, hi = region.lo;
  for (int z = region.lo.z(); z <= region.hi.z(); ++z)
    for (int y = region.lo.y(); y <= region.hi.y(); ++y)
      for (int x = region.lo.x(); x <= region.hi.x(); ++x) {
        const Vec3i v(x, y, z);
        if (components.label[box_index(region, v)] != c) continue;
        s.voxels.push_back(v);
        lo = lo.cwiseMin(v);
        hi = hi.cwiseMax(v);
      }
  s.extent_vox = hi - lo + Vec3i::Ones();
  return s;
}

}  // namespace

BrightStructure bright_structure(const volume::Volume& smoothed, const InsideRegion& region,
                                 bool needle_seen) {
  const Components components = label_components(smoothed, region);
  const std::vector<long>& size = components.size;
  if (size.empty()) return {};
  const auto largest = std::max_element(size.begin(), size.end());
  const long all = std::accumulate(size.begin(), size.end(), 0L);
  if (!needle_seen && 2 * *largest < all) return {};  // the speckle of a dark inside
  return component(region, components, static_cast<int>(largest - size.begin()));
}

BrightStructure deepest_bright_structure(const volume::Volume& smoothed,
                                         const InsideRegion& region) {
  const Components components = label_components(smoothed, region);
  const std::vector<long>& deep = components.deep;
  if (deep.empty()) return {};
  return component(region, components,
                   static_cast<int>(std::max_element(deep.begin(), deep.end()) - deep.begin()));
}

bool solid_inside(const BrightStructure& structure) { return structure.deep_vox > kLeastDeepVox; }

namespace {

// The longest stretch along the line through `a` along unit `u` (index space) of the points
// within 1.5 voxels of it, no gap of more than two voxels, in mm.
float stretch_mm(const std::vector<Vec3f>& points, const Vec3f& a, const Vec3f& u,
                 const Vec3f& spacing_mm) {
  constexpr float kThinVox2 = 1.5f * 1.5f;
  constexpr float kMostGapVox = 3.0f;
  std::vector<float> along;
  for (const Vec3f& p : points) {
    const Vec3f r = p - a;
    const float t = r.dot(u);
    if (r.squaredNorm() - t * t <= kThinVox2) along.push_back(t);
  }
  std::sort(along.begin(), along.end());
  float longest = 0.0f;
  for (std::size_t i = 0, start = 0; i < along.size(); ++i) {
    if (i > 0 && along[i] - along[i - 1] > kMostGapVox) start = i;
    longest = std::max(longest, along[i] - along[start] + 1.0f);
  }
  return longest * u.cwiseProduct(spacing_mm).norm();
}

}  // namespace

DeepLine deep_on_a_line(const volume::Volume& smoothed, const InsideRegion& region,
                        const BrightStructure& structure) {
  constexpr int kLines = 200;
  constexpr std::size_t kMostSampled = 4096;
  constexpr float kNearVox2 = 3.0f * 3.0f;
  std::vector<Vec3f> deep;
  for (const Vec3i& v : structure.voxels)
    if (deep_inside(smoothed, region, v)) deep.push_back(v.cast<float>());
  if (deep.size() < 2) return {.voxels = static_cast<long>(deep.size())};
  std::mt19937 random(1);  // (the same lines on every run: the verdict is repeatable)
  const std::size_t all = deep.size();
  if (all > kMostSampled) {
    std::shuffle(deep.begin(), deep.end(), random);
    deep.resize(kMostSampled);
  }
  std::uniform_int_distribution<std::size_t> pick(0, deep.size() - 1);
  long most = 0;
  Vec3f best_a = Vec3f::Zero(), best_u = Vec3f::UnitX();
  for (int line = 0; line < kLines; ++line) {
    const Vec3f a = deep[pick(random)];
    const Vec3f d = deep[pick(random)] - a;
    if (d.isZero()) continue;
    const Vec3f u = d.normalized();
    long near = 0;
    for (const Vec3f& p : deep) {
      const Vec3f r = p - a;
      const float along = r.dot(u);
      near += r.squaredNorm() - along * along <= kNearVox2;
    }
    if (near > most) most = near, best_a = a, best_u = u;
  }
  return {.voxels = static_cast<long>(static_cast<double>(most) * static_cast<double>(all) /
                                      static_cast<double>(deep.size())),
          .length_mm = stretch_mm(deep, best_a, best_u, smoothed.spacing_mm())};
}

bool passed_over(const BrightStructure& structure, const InsideRegion& region) {
  const int region_extent = (region.hi - region.lo + Vec3i::Ones()).maxCoeff();
  return solid_inside(structure) &&
         4 * structure.deep_vox >= static_cast<long>(structure.voxels.size()) &&
         2 * structure.extent_vox.maxCoeff() >= region_extent;
}

segment::PointCloud bright_walls(const volume::Volume& smoothed, const InsideRegion& region,
                                 const BrightStructure& structure) {
  segment::PointCloud walls;
  const Vec3f spacing = smoothed.spacing_mm();
  for (const Vec3i& v : structure.voxels)
    for (const Vec3i& face : kFaces) {
      const Vec3i q = v + face;
      if (!smoothed.contains_index(q) || !(value(smoothed, q) <= region.mid_level) ||
          !region.inside(q))
        continue;
      const float t =
          (region.mid_level - value(smoothed, q)) / (value(smoothed, v) - value(smoothed, q));
      const Vec3f p = smoothed.index_to_mm(q.cast<float>() + t * face.cast<float>());
      const Vec3f g = gradient_at(smoothed, p);
      if (!(g.norm() > 0.0f)) continue;
      walls.points.push_back(p);
      walls.normals.push_back(g.normalized());
      const int axis = face.x() != 0 ? 0 : face.y() != 0 ? 1 : 2;
      walls.area_mm2.push_back(spacing.prod() / spacing[axis]);
    }
  return walls;
}

InsideRegion inside_labels(const volume::Volume& labels, const mesh::Box& box,
                           const segment::BalloonStats& levels) {
  InsideRegion region;
  index_box(labels, box, region);
  region.mid_level = mid_level(levels);
  region.inside = [&labels](const Vec3i& v) {
    return labels.u8()[labels.linear_index(v.x(), v.y(), v.z())] != 0;
  };
  return region;
}

InsideRegion inside_indicator(const volume::Volume& smoothed, const volume::Volume& indicator,
                              float iso, const mesh::Box& box,
                              const segment::BalloonStats& levels) {
  InsideRegion region;
  index_box(smoothed, box, region);
  region.mid_level = mid_level(levels);
  region.inside = [&smoothed, &indicator, iso](const Vec3i& v) {
    const Vec3f p = smoothed.index_to_mm(v.cast<float>());
    return indicator.contains_mm(p) && volume::sample_mm(indicator, p) > iso;
  };
  return region;
}

std::optional<reconstruct::SurfaceResult> with_bright_walls(
    const volume::Volume& smoothed, const InsideRegion& region, mesh::PointCloud samples,
    const Vec3f& seed_mm, const reconstruct::PoissonOptions& poisson, bool needle_seen) {
  const BrightStructure structure = bright_structure(smoothed, region, needle_seen);
  if (!passed_over(structure, region)) return std::nullopt;
  const mesh::PointCloud walls = bright_walls(smoothed, region, structure);
  samples.points.insert(samples.points.end(), walls.points.begin(), walls.points.end());
  samples.normals.insert(samples.normals.end(), walls.normals.begin(), walls.normals.end());
  samples.area_mm2.insert(samples.area_mm2.end(), walls.area_mm2.begin(), walls.area_mm2.end());
  return reconstruct::reconstruct_surface(samples, seed_mm, poisson);
}

bool open_bright_inside(const volume::Volume& smoothed, const segment::PointCloud& samples,
                        const Vec3f& seed_mm, const reconstruct::PoissonOptions& poisson,
                        const segment::BalloonStats& levels, bool needle_seen,
                        reconstruct::SurfaceResult& surface) {
  const auto t = Clock::now();  // (the search is the reconstruction's: timed with it)
  const InsideRegion region = inside_indicator(smoothed, surface.indicator, surface.iso,
                                               mesh::bounding_box(surface.mesh), levels);
  std::optional<reconstruct::SurfaceResult> again =
      with_bright_walls(smoothed, region, samples, seed_mm, poisson, needle_seen);
  if (!again || again->mesh.triangles.empty() || !again->seed_enclosed) {
    surface.reconstruct_ms += ms_since(t);
    return false;
  }
  again->reconstruct_ms = surface.reconstruct_ms + ms_since(t) - again->mesh_ms;
  again->mesh_ms += surface.mesh_ms;
  surface = std::move(*again);
  return true;
}

}  // namespace sonomesh::daemon::internal
