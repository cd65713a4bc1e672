// The warm start's checks (warm_start.h); the start mesh itself is warm_interior.h's. A_t is not
// carried over from the previous volume and the start mesh's interior is not marked in it either
// (balloon_evolution.h says why).
#include "segment/internal/warm_start.h"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <limits>
#include <vector>

#include "mesh/parallel.h"

namespace sonomesh::segment::internal {
namespace {

// Area-weighted vertex normals (unit; zero where the faces cancel) of `vertices` points, the
// triangles handed out by for_each_triangle(add) as add(a, b, c) with counter-clockwise indices.
template <class Position, class ForEachTriangle>
std::vector<Vec3f> area_weighted_normals(std::size_t vertices, Position position,
                                         ForEachTriangle for_each_triangle) {
  std::vector<Vec3f> n(vertices, Vec3f::Zero());
  for_each_triangle([&](std::uint32_t a, std::uint32_t b, std::uint32_t c) {
    const Vec3f pa = position(a);
    const Vec3f face = (position(b) - pa).cross(position(c) - pa);
    n[a] += face;
    n[b] += face;
    n[c] += face;
  });
  for (Vec3f& v : n) {
    const float len = v.norm();
    v = len > 0.0f ? Vec3f(v / len) : Vec3f::Zero();
  }
  return n;
}

// (Not mesh::vertex_normals, equation (2)'s: these weigh each triangle by its area.)
std::vector<Vec3f> area_normals(const Mesh& m) {
  return area_weighted_normals(
      m.vertices.size(), [&](std::uint32_t v) { return m.vertices[v]; },
      [&](auto add) {
        for (const auto& t : m.triangles) add(t[0], t[1], t[2]);
      });
}

}  // namespace

std::vector<Vec3f> vertex_normals(const BalloonMesh& m) {
  return area_weighted_normals(
      m.n_vertices(), [&](std::uint32_t v) { return m.point_mm(Vertex{v}); },
      [&](auto add) {
        for (std::uint32_t f = 0; f < m.n_faces(); ++f) {
          if (m.is_deleted(Face{f})) continue;
          const Halfedge h = m.halfedge(Face{f});
          add(m.to_vertex(h).idx, m.to_vertex(m.next(h)).idx, m.to_vertex(m.next(m.next(h))).idx);
        }
      });
}

namespace {

// The mean level over a 3×3×3 lattice `spacing_mm` apart centred on p, in the cost's scale.
float region_level(const ImageSampler& sampler, const CostScale& scale, const Vec3f& p,
                   float spacing_mm) {
  float sum = 0.0f;
  for (int k = -1; k <= 1; ++k)
    for (int j = -1; j <= 1; ++j)
      for (int i = -1; i <= 1; ++i)
        sum += scale.map(sampler.value(p + spacing_mm * Vec3f(i, j, k)));
  return sum / 27.0f;
}

}  // namespace

std::string check_start_safe(const BalloonMesh& start, const ImageSampler& sampler,
                             const CostScale& scale, float wall_level, const StepKernel& box,
                             const StartAllowance& allow) {
  int failed = 0, outside = 0, samples = 0;
  Vec3f first = Vec3f::Zero();
  auto test = [&](const Vec3f& p) {
    ++samples;
    const bool out = box.outside(p);
    if (!out && scale.map(sampler.value(p)) < wall_level) return;
    if (!out && allow.region_mm > 0.0f &&
        region_level(sampler, scale, p, allow.region_mm) < wall_level)
      return;  // a grain: the region around it is the inside's
    if (failed++ == 0) first = p;
    outside += out;
  };
  for (std::uint32_t v = 0; v < start.n_vertices(); ++v) test(start.point_mm(Vertex{v}));
  for (std::uint32_t e = 0; e < start.n_edges(); ++e) {
    const Halfedge h = BalloonMesh::halfedge(Edge{e}, 0);
    test(0.5f * (start.point_mm(start.from_vertex(h)) + start.point_mm(start.to_vertex(h))));
  }
  if (outside == 0 && static_cast<float>(failed) <= allow.share * static_cast<float>(samples))
    return {};
  char where[96];
  std::snprintf(where, sizeof where, "(%.1f, %.1f, %.1f) mm", first.x(), first.y(), first.z());
  return std::to_string(failed) + " of " + std::to_string(samples) +
         " start samples lie on or past a wall or outside the volume, the first at " + where;
}

std::string check_walls_kept(const Mesh& previous, std::span<const StopReason> stop,
                             const ImageSampler& sampler, const CostScale& scale, float wall_level,
                             float seed_level, float reach_mm, float vox_mm,
                             const StepKernel& box) {
  // A wall: the level reaches the wall's, or rises along the normal by half the climb to it (a
  // wall in a shadow, where the relative cost stopped the vertex below the wall's level).
  const float min_rise = 0.5f * (wall_level - scale.map(seed_level));
  if (stop.size() != previous.vertices.size()) return {};  // (no stop reasons: nothing to check)
  const std::vector<Vec3f> normal = area_normals(previous);
  const float step_mm = 0.5f * vox_mm;
  const int steps = static_cast<int>(std::ceil(reach_mm / step_mm));
  int walls = 0, lost = 0;
  for (std::size_t v = 0; v < stop.size(); ++v) {
    if (stop[v] != StopReason::Boundary) continue;
    ++walls;
    bool found = false;
    float lowest = std::numeric_limits<float>::max();
    for (int k = -steps; k <= steps && !found; ++k) {
      const Vec3f p = previous.vertices[v] + (static_cast<float>(k) * step_mm) * normal[v];
      if (box.outside(p)) {
        found = true;
        break;
      }
      const float level = scale.map(sampler.value(p));
      lowest = std::min(lowest, level);
      found = level >= wall_level || level - lowest >= min_rise;
    }
    lost += !found;
  }
  // (96³ cyst-needle at 0.5 mm: a breath loses 3-6 % of the walls, a withdrawn needle 18 %.)
  if (walls == 0 || lost * 10 <= walls) return {};
  return std::to_string(lost) + " of " + std::to_string(walls) +
         " walls the previous balloon stopped at are gone";
}

void init_start_states(BalloonMesh& start, const ImageSampler& sampler, const CostScale& scale,
                       float seed_level) {
  const float seed = scale.map(seed_level);
  for (std::uint32_t v = 0; v < start.n_vertices(); ++v) {
    const float level = scale.map(sampler.value(start.point_mm(Vertex{v})));
    VertexState& s = start.state(Vertex{v});
    s.cost = std::max(0.0f, level - seed);
    s.floor_level = std::min(level, seed);
    s.anchor_mm = start.point_mm(Vertex{v});
  }
}

void replay_start_states(BalloonMesh& start, const ImageSampler& sampler, const CostRule& cost,
                         const ReplayPath& path, const StepKernel& box, int threads) {
  const std::vector<Vec3f> normal = vertex_normals(start);
  const int floor_steps = static_cast<int>(path.floor_mm / path.step_mm);
  const int cost_steps = static_cast<int>(path.cost_mm / path.step_mm);
  mesh::Workers workers(threads);
  workers.parallel_for(start.n_vertices(), 256, [&](std::size_t b, std::size_t e) {
    for (std::size_t v = b; v < e; ++v) {
      const Vertex vertex{static_cast<std::uint32_t>(v)};
      if (start.is_deleted(vertex) || normal[v].isZero()) continue;
      const Vec3f p = start.point_mm(vertex);
      const Vec3f step = path.step_mm * normal[v];
      VertexState& s = start.state(vertex);
      // Back along -n, the darkest level on the way, until a wall behind (a thin part's other
      // side) or the volume's edge.
      int back = 0;
      float floor_level = s.floor_level;
      while (back < floor_steps) {
        const Vec3f q = p - static_cast<float>(back + 1) * step;
        if (box.outside(q)) break;
        const float level = cost.scale.map(sampler.value(q));
        if (level >= path.wall_level) break;
        floor_level = std::min(floor_level, level);
        ++back;
      }
      // Then forward again over the cost's reach, Ψ_cost as the evolution sums it.
      float c = 0.0f, path_mm = 0.0f;
      bool stopped = false;
      for (int k = std::min(back, cost_steps); k > 0; --k)
        cost.advance(sampler, p - static_cast<float>(k) * step, step, c, floor_level, path_mm,
                     stopped);
      // (Capped at τ_cost: a replay that would have stopped leaves the vertex to its first rise.)
      s.cost = std::max(s.cost, std::min(c, cost.tau));
      s.floor_level = std::min(s.floor_level, floor_level);
    }
  });
}

}  // namespace sonomesh::segment::internal
