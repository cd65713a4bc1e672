// The warm start's start mesh (warm_start.h). A_t is not carried over from the previous volume
// and the start mesh's interior is not marked in it either (balloon_evolution.h says why).
#include "segment/internal/warm_start.h"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <limits>
#include <vector>

namespace sonomesh::segment::internal {
namespace {

// Smoothing before the inset: two umbrella steps of this weight round the creases the balloon
// left where it met itself, so the inset does not fold them. They move a crease by a fraction of
// a voxel, well inside the inset's 2 voxels.
constexpr int kSmoothingSteps = 2;
constexpr float kSmoothingWeight = 0.3f;
constexpr int kRemeshPasses = 3;

constexpr int kUnfoldRounds = 4;

// Unique neighbours of every vertex, from the triangles.
std::vector<std::vector<std::uint32_t>> neighbours(const Mesh& m) {
  std::vector<std::vector<std::uint32_t>> out(m.vertices.size());
  for (const auto& t : m.triangles)
    for (int k = 0; k < 3; ++k) {
      out[t[k]].push_back(t[(k + 1) % 3]);
      out[t[k]].push_back(t[(k + 2) % 3]);
    }
  for (auto& n : out) {
    std::sort(n.begin(), n.end());
    n.erase(std::unique(n.begin(), n.end()), n.end());
  }
  return out;
}

// Umbrella steps: each vertex moves kSmoothingWeight of the way to its neighbours' centroid.
void smooth(Mesh& m, const std::vector<std::vector<std::uint32_t>>& ring, int steps) {
  for (int step = 0; step < steps; ++step) {
    std::vector<Vec3f> next = m.vertices;
    for (std::size_t v = 0; v < m.vertices.size(); ++v) {
      Vec3f centroid = Vec3f::Zero();
      for (const std::uint32_t q : ring[v]) centroid += m.vertices[q];
      centroid /= static_cast<float>(ring[v].size());
      next[v] += kSmoothingWeight * (centroid - m.vertices[v]);
    }
    m.vertices = std::move(next);
  }
}

// Area-weighted vertex normals (unit; zero where the faces cancel).
std::vector<Vec3f> vertex_normals(const Mesh& m) {
  std::vector<Vec3f> n(m.vertices.size(), Vec3f::Zero());
  for (const auto& t : m.triangles) {
    const Vec3f a = m.vertices[t[0]], b = m.vertices[t[1]], c = m.vertices[t[2]];
    const Vec3f face = (b - a).cross(c - a);
    for (const std::uint32_t v : t) n[v] += face;
  }
  for (Vec3f& v : n) {
    const float len = v.norm();
    v = len > 0.0f ? Vec3f(v / len) : Vec3f::Zero();
  }
  return n;
}

double signed_volume_mm3(const Mesh& m) {
  double six_v = 0.0;
  for (const auto& t : m.triangles)
    six_v += m.vertices[t[0]].cast<double>().dot(
        m.vertices[t[1]].cast<double>().cross(m.vertices[t[2]].cast<double>()));
  return six_v / 6.0;
}

// Folded by the inset: a face whose normal turned against its old one.
int folded_faces(const Mesh& before, const Mesh& after) {
  int folded = 0;
  for (const auto& t : before.triangles) {
    auto normal = [&](const Mesh& m) {
      return Vec3f(
          (m.vertices[t[1]] - m.vertices[t[0]]).cross(m.vertices[t[2]] - m.vertices[t[0]]));
    };
    folded += normal(before).dot(normal(after)) <= 0.0f;
  }
  return folded;
}

}  // namespace

std::string prepare_start_mesh(const Mesh& previous, float inset_mm, const RemeshLimits& limits,
                               BalloonMesh& out) {
  if (previous.vertices.size() < 4 || previous.triangles.size() < 4)
    return "the previous balloon has no surface";
  if (mesh::euler_characteristic(previous) != 2) return "the previous balloon is not genus 0";
  Mesh m = previous;
  const auto ring = neighbours(m);
  for (const auto& r : ring)
    if (r.empty()) return "the previous balloon has an isolated vertex";
  smooth(m, ring, kSmoothingSteps);
  const Mesh smoothed = m;
  const std::vector<Vec3f> normal = vertex_normals(m);
  for (std::size_t v = 0; v < m.vertices.size(); ++v) m.vertices[v] -= inset_mm * normal[v];
  // The inset folds a crease tighter than itself (the groove around a needle): smoothing the
  // moved mesh unfolds it, a few steps at a time.
  int folded = folded_faces(smoothed, m);
  for (int round = 0; round < kUnfoldRounds && folded > 0; ++round) {
    smooth(m, ring, kSmoothingSteps);
    folded = folded_faces(smoothed, m);
  }
  // Even a few folded faces are refused: left in (tried at 2 % of the faces, on the seam behind
  // a needle where two sheets met) they turned the balloon through the needle and it leaked.
  if (folded > 0)
    return std::to_string(folded) + " faces folded when moved " + std::to_string(inset_mm) +
           " mm inward (a part thinner than twice that)";
  if (!(signed_volume_mm3(m) > 0.0)) return "the inset left no enclosed volume";
  try {
    from_plain_mesh(m, out);
  } catch (const std::invalid_argument& e) {
    return std::string("the previous balloon is not manifold: ") + e.what();
  }
  for (int pass = 0; pass < kRemeshPasses; ++pass) remesh(out, limits);
  if (std::string why = validate(out); !why.empty()) return "the start mesh is invalid: " + why;
  return {};
}

std::string check_start_safe(const BalloonMesh& start, const ImageSampler& sampler,
                             const CostScale& scale, float wall_level, const StepKernel& box) {
  int failed = 0, samples = 0;
  Vec3f first = Vec3f::Zero();
  auto test = [&](const Vec3f& p) {
    ++samples;
    if (!box.outside(p) && scale.map(sampler.value(p)) < wall_level) return;
    if (failed++ == 0) first = p;
  };
  for (std::uint32_t v = 0; v < start.n_vertices(); ++v) test(start.point_mm(Vertex{v}));
  for (std::uint32_t e = 0; e < start.n_edges(); ++e) {
    const Halfedge h = BalloonMesh::halfedge(Edge{e}, 0);
    test(0.5f * (start.point_mm(start.from_vertex(h)) + start.point_mm(start.to_vertex(h))));
  }
  if (failed == 0) return {};
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
  const std::vector<Vec3f> normal = vertex_normals(previous);
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

}  // namespace sonomesh::segment::internal
