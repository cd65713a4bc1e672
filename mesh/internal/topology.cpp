// Mesh counts and checks (Euler characteristic, watertightness, vertex fans), components and
// point-in-mesh tests.

#include <Eigen/Geometry>
#include <algorithm>
#include <cmath>
#include <numeric>
#include <stdexcept>
#include <string>

#include "mesh/mesh.h"

namespace sonomesh::mesh {
namespace {

struct UnionFind {
  std::vector<std::uint32_t> parent;
  explicit UnionFind(std::size_t n) : parent(n) { std::iota(parent.begin(), parent.end(), 0u); }
  std::uint32_t find(std::uint32_t a) {
    while (parent[a] != a) a = parent[a] = parent[parent[a]];
    return a;
  }
  void unite(std::uint32_t a, std::uint32_t b) {
    a = find(a);
    b = find(b);
    if (a != b) parent[std::max(a, b)] = std::min(a, b);
  }
};

void check_indices(const Mesh& mesh, const char* who) {
  const auto n = mesh.vertices.size();
  for (const auto& t : mesh.triangles)
    for (auto v : t)
      if (v >= n)
        throw std::invalid_argument(std::string(who) + ": triangle index " + std::to_string(v) +
                                    " out of range (" + std::to_string(n) + " vertices)");
}

// Component label per vertex (only meaningful for referenced vertices), labels 0..count-1.
std::vector<int> vertex_components(const Mesh& mesh, int* count) {
  UnionFind uf(mesh.vertices.size());
  for (const auto& t : mesh.triangles) {
    uf.unite(t[0], t[1]);
    uf.unite(t[1], t[2]);
  }
  std::vector<char> used(mesh.vertices.size(), 0);
  for (const auto& t : mesh.triangles) used[t[0]] = used[t[1]] = used[t[2]] = 1;
  std::vector<int> label(mesh.vertices.size(), -1), root_label(mesh.vertices.size(), -1);
  int n = 0;
  for (std::uint32_t v = 0; v < mesh.vertices.size(); ++v) {
    if (!used[v]) continue;
    const auto r = uf.find(v);
    if (root_label[r] < 0) root_label[r] = n++;
    label[v] = root_label[r];
  }
  *count = n;
  return label;
}

double signed_volume_mm3(const Mesh& mesh) {
  double vol = 0.0;
  for (const auto& t : mesh.triangles) {
    const Eigen::Vector3d a = mesh.vertices[t[0]].cast<double>();
    const Eigen::Vector3d b = mesh.vertices[t[1]].cast<double>();
    const Eigen::Vector3d c = mesh.vertices[t[2]].cast<double>();
    vol += a.dot(b.cross(c));
  }
  return vol / 6.0;
}

// The undirected edges, each listed at its lower vertex: per vertex v, the higher ends of its
// half-edges (a, b) with min(a, b) = v, the direction in the lowest bit. A vertex's list is a
// handful of entries, so small sorts replace a sort of every half-edge. An edge is closed when
// it is exactly {(a, b), (b, a)}. Counts the undirected edges, per component of `label` if given.
struct EdgeCount {
  int edges = 0;
  bool watertight = false;
};

EdgeCount count_edges(const Mesh& mesh, const std::vector<int>* label,
                      std::vector<int>* edges_per_comp) {
  const std::size_t nv = mesh.vertices.size();
  std::vector<std::uint32_t> start(nv + 1, 0);
  for (const auto& t : mesh.triangles)
    for (int i = 0; i < 3; ++i) ++start[std::min(t[i], t[(i + 1) % 3]) + 1];
  for (std::size_t v = 0; v < nv; ++v) start[v + 1] += start[v];
  std::vector<std::uint32_t> fill(start.begin(), start.end() - 1);
  std::vector<std::uint64_t> ends(start[nv]);
  for (const auto& t : mesh.triangles)
    for (int i = 0; i < 3; ++i) {
      const std::uint32_t a = t[i], b = t[(i + 1) % 3];
      const std::uint32_t lo = std::min(a, b), hi = std::max(a, b);
      ends[fill[lo]++] = std::uint64_t(hi) << 1 | (a < b ? 0u : 1u);
    }
  EdgeCount count;
  count.watertight = !mesh.triangles.empty();
  for (std::size_t v = 0; v < nv; ++v) {
    const auto first = ends.begin() + start[v], last = ends.begin() + start[v + 1];
    std::sort(first, last);
    for (auto i = first; i != last;) {
      auto j = i;
      while (j != last && (*j >> 1) == (*i >> 1)) ++j;
      // Exactly two, one each way (sorted: the direction bits 0 then 1).
      if (j - i != 2 || (*i & 1u) == (*(i + 1) & 1u)) count.watertight = false;
      ++count.edges;
      if (label) ++(*edges_per_comp)[(*label)[v]];
      i = j;
    }
  }
  return count;
}

// Closed manifold at every referenced vertex v: the link edges (b, c) of its faces (v, b, c)
// form one cycle. Every neighbour starting exactly one link edge and ending one is the
// watertight condition seen from v (each halfedge once, its twin once); following the edges from
// one neighbour back to it in deg steps is the single fan.
bool closed_fans(const Mesh& mesh) {
  const std::size_t nv = mesh.vertices.size();
  std::vector<std::uint32_t> start(nv + 1, 0);
  for (const auto& t : mesh.triangles)
    for (auto v : t) ++start[v + 1];
  for (std::size_t v = 0; v < nv; ++v) start[v + 1] += start[v];
  std::vector<std::uint32_t> fill(start.begin(), start.end() - 1), incident(start[nv]);
  for (std::uint32_t f = 0; f < mesh.triangles.size(); ++f)
    for (auto v : mesh.triangles[f]) incident[fill[v]++] = f;
  std::vector<std::pair<std::uint32_t, std::uint32_t>> link;  // (b, c), sorted by b
  std::vector<std::uint32_t> ends;
  for (std::uint32_t v = 0; v < nv; ++v) {
    const std::uint32_t deg = start[v + 1] - start[v];
    if (deg == 0) continue;
    link.clear();
    ends.clear();
    for (auto i = start[v]; i < start[v + 1]; ++i) {
      const auto& t = mesh.triangles[incident[i]];
      const int at = t[0] == v ? 0 : (t[1] == v ? 1 : 2);
      link.emplace_back(t[(at + 1) % 3], t[(at + 2) % 3]);
      ends.push_back(t[(at + 2) % 3]);
    }
    std::sort(link.begin(), link.end());
    std::sort(ends.begin(), ends.end());
    for (std::uint32_t i = 0; i < deg; ++i)
      if (link[i].first != ends[i] || (i > 0 && ends[i] == ends[i - 1])) return false;
    std::uint32_t at = link[0].first, steps = 0;
    do {
      const auto next =
          std::lower_bound(link.begin(), link.end(), std::make_pair(at, std::uint32_t{0}));
      at = next->second;
      ++steps;
    } while (at != link[0].first && steps <= deg);
    if (steps != deg) return false;
  }
  return true;
}

}  // namespace

Topology analyze_topology(const Mesh& mesh) {
  check_indices(mesh, "analyze_topology");
  Topology topo;
  int n_comp = 0;
  const auto label = vertex_components(mesh, &n_comp);
  topo.components = n_comp;
  topo.faces = static_cast<int>(mesh.triangles.size());
  topo.vertices =
      static_cast<int>(std::count_if(label.begin(), label.end(), [](int l) { return l >= 0; }));
  std::vector<int> edges_per_comp(n_comp, 0), verts_per_comp(n_comp, 0), faces_per_comp(n_comp, 0);
  const EdgeCount edges = count_edges(mesh, &label, &edges_per_comp);
  topo.edges = edges.edges;
  for (std::size_t v = 0; v < label.size(); ++v)
    if (label[v] >= 0) ++verts_per_comp[label[v]];
  for (const auto& t : mesh.triangles) ++faces_per_comp[label[t[0]]];
  topo.euler = topo.vertices - topo.edges + topo.faces;
  for (int c = 0; c < n_comp; ++c)
    topo.genus += (2 - (verts_per_comp[c] - edges_per_comp[c] + faces_per_comp[c])) / 2;
  topo.watertight = edges.watertight;
  topo.manifold = edges.watertight && closed_fans(mesh);
  topo.volume_ml = enclosed_volume_ml(mesh);
  return topo;
}

bool is_closed_manifold(const Mesh& mesh) {
  check_indices(mesh, "is_closed_manifold");
  return !mesh.triangles.empty() && closed_fans(mesh);
}

int euler_characteristic(const Mesh& mesh) {
  check_indices(mesh, "euler_characteristic");
  int n_comp = 0;
  const auto label = vertex_components(mesh, &n_comp);
  const auto vertices = std::count_if(label.begin(), label.end(), [](int l) { return l >= 0; });
  return static_cast<int>(vertices) - count_edges(mesh, nullptr, nullptr).edges +
         static_cast<int>(mesh.triangles.size());
}

double enclosed_volume_ml(const Mesh& mesh) { return signed_volume_mm3(mesh) / 1000.0; }

double surface_area_mm2(const Mesh& mesh) {
  check_indices(mesh, "surface_area_mm2");
  double area = 0.0;
  for (const auto& t : mesh.triangles)
    area += 0.5 * (mesh.vertices[t[1]] - mesh.vertices[t[0]])
                      .cross(mesh.vertices[t[2]] - mesh.vertices[t[0]])
                      .norm();
  return area;
}

double thickness_mm(const Mesh& closed_mesh) {
  const double area_mm2 = surface_area_mm2(closed_mesh);
  return area_mm2 > 0.0 ? 3e3 * enclosed_volume_ml(closed_mesh) / area_mm2 : 0.0;
}

Box bounding_box(const Mesh& mesh) {
  if (mesh.vertices.empty()) return {};
  Box box{mesh.vertices.front(), mesh.vertices.front()};
  for (const Vec3f& p : mesh.vertices) {
    box.lo_mm = box.lo_mm.cwiseMin(p);
    box.hi_mm = box.hi_mm.cwiseMax(p);
  }
  return box;
}

std::vector<Mesh> connected_components(const Mesh& mesh) {
  check_indices(mesh, "connected_components");
  int n = 0;
  const auto label = vertex_components(mesh, &n);
  std::vector<Mesh> out(n);
  std::vector<std::uint32_t> new_index(mesh.vertices.size(), 0);
  for (std::uint32_t v = 0; v < mesh.vertices.size(); ++v) {
    if (label[v] < 0) continue;
    auto& m = out[label[v]];
    new_index[v] = static_cast<std::uint32_t>(m.vertices.size());
    m.vertices.push_back(mesh.vertices[v]);
  }
  for (const auto& t : mesh.triangles)
    out[label[t[0]]].triangles.push_back({new_index[t[0]], new_index[t[1]], new_index[t[2]]});
  return out;
}

bool encloses(const Mesh& mesh, const Vec3f& p_mm) {
  check_indices(mesh, "encloses");
  // A ray along an irrational direction practically never meets an edge or a vertex exactly.
  const Eigen::Vector3d dir =
      Eigen::Vector3d(1.0, 0.000317 * std::sqrt(2.0), 0.000271 * std::sqrt(3.0)).normalized();
  const Eigen::Vector3d o = p_mm.cast<double>();
  int hits = 0;
  for (const auto& t : mesh.triangles) {
    // Möller–Trumbore.
    const Eigen::Vector3d a = mesh.vertices[t[0]].cast<double>();
    const Eigen::Vector3d e1 = mesh.vertices[t[1]].cast<double>() - a;
    const Eigen::Vector3d e2 = mesh.vertices[t[2]].cast<double>() - a;
    const Eigen::Vector3d pv = dir.cross(e2);
    const double det = e1.dot(pv);
    if (std::abs(det) < 1e-300) continue;
    const Eigen::Vector3d tv = o - a;
    const double u = tv.dot(pv) / det;
    if (u < 0.0 || u > 1.0) continue;
    const Eigen::Vector3d qv = tv.cross(e1);
    const double w = dir.dot(qv) / det;
    if (w < 0.0 || u + w > 1.0) continue;
    if (e2.dot(qv) / det > 0.0) ++hits;
  }
  return hits % 2 == 1;
}

Mesh component_enclosing(const Mesh& mesh, const Vec3f& seed_mm, bool* seed_enclosed,
                         int* component_count) {
  auto comps = connected_components(mesh);
  if (component_count) *component_count = static_cast<int>(comps.size());
  int best = -1;
  double best_volume = 0.0;
  for (int c = 0; c < static_cast<int>(comps.size()); ++c) {
    if (!encloses(comps[c], seed_mm)) continue;
    const double vol = std::abs(signed_volume_mm3(comps[c]));
    if (best < 0 || vol < best_volume) {
      best = c;
      best_volume = vol;
    }
  }
  if (seed_enclosed) *seed_enclosed = best >= 0;
  if (best < 0) {
    for (int c = 0; c < static_cast<int>(comps.size()); ++c)
      if (best < 0 || comps[c].triangles.size() > comps[best].triangles.size()) best = c;
  }
  if (best < 0) return {};
  return std::move(comps[best]);
}

}  // namespace sonomesh::mesh
