// Filling the surface's tunnels through the target's own darkness (reconstruct.h).
#include <algorithm>
#include <limits>
#include <vector>

#include "mesh/parallel.h"
#include "reconstruct/reconstruct.h"

namespace sonomesh::reconstruct {
namespace {

using volume::Vec3i;

// One slice of χ across `axis` at `s`, within the box [lo, hi] (grid cells): cell (u, v) of the
// slice is grid cell at(u, v), u and v counted from the box's corner.
struct Slice {
  const volume::Volume& chi;
  int axis, s;
  Vec3i lo, hi;
  int du() const { return hi[(axis + 1) % 3] - lo[(axis + 1) % 3] + 1; }
  int dv() const { return hi[(axis + 2) % 3] - lo[(axis + 2) % 3] + 1; }
  Vec3i at(int u, int v) const {
    Vec3i c;
    c[axis] = s;
    c[(axis + 1) % 3] = lo[(axis + 1) % 3] + u;
    c[(axis + 2) % 3] = lo[(axis + 2) % 3] + v;
    return c;
  }
};

// The slice's holes: outside cells (4-connected) that do not reach the box's border, each hole
// as its list of cells.
std::vector<std::vector<Vec3i>> slice_holes(const Slice& slice, float iso) {
  const int nu = slice.du(), nv = slice.dv();
  std::vector<std::uint8_t> seen(static_cast<std::size_t>(nu) * nv, 0);
  auto inside = [&](int u, int v) {
    const Vec3i c = slice.at(u, v);
    return slice.chi.f32()[slice.chi.linear_index(c.x(), c.y(), c.z())] > iso;
  };
  std::vector<std::vector<Vec3i>> holes;
  std::vector<std::pair<int, int>> stack;
  for (int v0 = 0; v0 < nv; ++v0)
    for (int u0 = 0; u0 < nu; ++u0) {
      if (seen[v0 * nu + u0] || inside(u0, v0)) continue;
      std::vector<Vec3i> cells;
      bool border = false;
      stack.assign(1, {u0, v0});
      seen[v0 * nu + u0] = 1;
      while (!stack.empty()) {
        const auto [u, v] = stack.back();
        stack.pop_back();
        cells.push_back(slice.at(u, v));
        border = border || u == 0 || v == 0 || u == nu - 1 || v == nv - 1;
        const int next[4][2] = {{u + 1, v}, {u - 1, v}, {u, v + 1}, {u, v - 1}};
        for (const auto& [a, b] : next)
          if (a >= 0 && b >= 0 && a < nu && b < nv && !seen[b * nu + a] && !inside(a, b)) {
            seen[b * nu + a] = 1;
            stack.emplace_back(a, b);
          }
      }
      if (!border) holes.push_back(std::move(cells));
    }
  return holes;
}

// The inside cells' box grown by one cell (clipped to the grid): outside it nothing is enclosed,
// and its rim is outside. Empty (lo > hi) when nothing is inside.
std::pair<Vec3i, Vec3i> inside_box(const volume::Volume& chi, float iso) {
  Vec3i lo = chi.dims(), hi = Vec3i::Constant(-1);
  for (int k = 0; k < chi.dims().z(); ++k)
    for (int j = 0; j < chi.dims().y(); ++j)
      for (int i = 0; i < chi.dims().x(); ++i)
        if (chi.f32()[chi.linear_index(i, j, k)] > iso) {
          lo = lo.cwiseMin(Vec3i(i, j, k));
          hi = hi.cwiseMax(Vec3i(i, j, k));
        }
  return {(lo - Vec3i::Ones()).cwiseMax(Vec3i::Zero()),
          (hi + Vec3i::Ones()).cwiseMin(chi.dims() - Vec3i::Ones())};
}

// The brightest the image gets over the cells: a needle's tunnel holds the needle, a false one
// nothing brighter than the inside.
float max_image(const volume::Volume& chi, const volume::Volume& image,
                const std::vector<Vec3i>& cells) {
  float brightest = -std::numeric_limits<float>::infinity();
  for (const Vec3i& c : cells)
    brightest = std::max(brightest, volume::sample_mm(image, chi.index_to_mm(c.cast<float>())));
  return brightest;
}

}  // namespace

std::vector<FilledCell> fill_dark_tunnels(volume::Volume& chi, float iso, float inside_value,
                                          const volume::Volume& image, float dark_below,
                                          int threads) {
  std::vector<FilledCell> filled;
  const std::pair<Vec3i, Vec3i> box = inside_box(chi, iso);
  const Vec3i lo = box.first, hi = box.second;  // (a lambda cannot capture structured bindings)
  mesh::Workers workers(threads);
  // The slices across one axis hold disjoint cells, so they are filled in parallel; an axis
  // sees what the axes before it filled. Each chunk's cells are appended in chunk order.
  std::vector<std::vector<FilledCell>> by_chunk(static_cast<std::size_t>(workers.threads()));
  for (int axis = 0; axis < 3; ++axis) {
    workers.parallel_chunks(lo[axis], hi[axis] + 1, [&](int first, int last, int chunk) {
      std::vector<FilledCell>& mine = by_chunk[static_cast<std::size_t>(chunk)];
      for (int s = first; s < last; ++s)
        for (const auto& hole : slice_holes(Slice{chi, axis, s, lo, hi}, iso)) {
          if (max_image(chi, image, hole) >= dark_below) continue;
          for (const Vec3i& c : hole) {
            const std::size_t at = chi.linear_index(c.x(), c.y(), c.z());
            mine.push_back({at, chi.f32()[at]});  // (outside: below iso < inside_value)
            chi.f32()[at] = inside_value;
          }
        }
    });
    for (std::vector<FilledCell>& mine : by_chunk) {
      filled.insert(filled.end(), mine.begin(), mine.end());
      mine.clear();
    }
  }
  return filled;
}

bool close_dark_tunnels(SurfaceResult& surface, const Vec3f& seed_mm, const volume::Volume& image,
                        float dark_below, int threads) {
  if (surface.topology.genus <= 0 || surface.indicator.empty()) return false;
  volume::Volume& chi = surface.indicator;
  const float at_seed = volume::sample_mm(chi, seed_mm);
  if (!(at_seed > surface.iso)) return false;
  const float inside_value = 0.5f * (surface.iso + at_seed);
  // χ is filled in place and given back unless the genus fell (no copy of the grid per volume).
  const std::vector<FilledCell> filled =
      fill_dark_tunnels(chi, surface.iso, inside_value, image, dark_below, threads);
  if (filled.empty()) return false;
  bool enclosed = false;
  Mesh mesh = mesh::component_enclosing(marching_cubes(chi, surface.iso), seed_mm, &enclosed);
  const Topology topology = analyze_topology(mesh);
  if (!enclosed || topology.genus >= surface.topology.genus || !topology.watertight) {
    for (const FilledCell& cell : filled) chi.f32()[cell.index] = cell.was;
    return false;
  }
  surface.mesh = std::move(mesh);
  surface.topology = topology;
  return true;
}

}  // namespace sonomesh::reconstruct
