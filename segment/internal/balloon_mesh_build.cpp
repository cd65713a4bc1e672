// The balloon mesh's construction, validation and conversion to a plain Mesh.
#include <algorithm>
#include <array>
#include <cmath>
#include <set>
#include <stdexcept>
#include <string>

#include "segment/internal/balloon_mesh.h"
#include "segment/internal/openmesh_order.h"

namespace sonomesh::segment::internal {

using namespace openmesh_order;

// ---------------------------------------------------------------------------------------------
// Construction, validation

void make_uv_sphere(BalloonMesh& out, const Vec3f& centre_mm, float radius_mm, int segments,
                    int bands) {
  if (segments < 3 || bands < 2 || !(radius_mm > 0.0f))
    throw std::invalid_argument("make_uv_sphere: need segments >= 3, bands >= 2, radius > 0");
  out.clear();
  const Vertex north = out.add_vertex(centre_mm + Vec3f(0.0f, 0.0f, radius_mm));
  std::vector<std::vector<Vertex>> rings;
  for (int k = 1; k < bands; ++k) {
    const double theta = M_PI * k / bands;
    std::vector<Vertex> ring;
    for (int j = 0; j < segments; ++j) {
      const double phi = 2.0 * M_PI * j / segments;
      const Vec3f p_mm(static_cast<float>(radius_mm * std::sin(theta) * std::cos(phi)),
                       static_cast<float>(radius_mm * std::sin(theta) * std::sin(phi)),
                       static_cast<float>(radius_mm * std::cos(theta)));
      ring.push_back(out.add_vertex(centre_mm + p_mm));
    }
    rings.push_back(std::move(ring));
  }
  const Vertex south = out.add_vertex(centre_mm - Vec3f(0.0f, 0.0f, radius_mm));
  // Orientation: counter-clockwise seen from outside (checked by validate()'s signed volume).
  for (int j = 0; j < segments; ++j) {
    const int jn = (j + 1) % segments;
    out.add_triangle(north, rings.front()[j], rings.front()[jn]);
    for (std::size_t k = 0; k + 1 < rings.size(); ++k) {
      const Vertex a = rings[k][j], b = rings[k][jn], d = rings[k + 1][j], cc = rings[k + 1][jn];
      out.add_triangle(a, d, cc);
      out.add_triangle(a, cc, b);
    }
    out.add_triangle(south, rings.back()[jn], rings.back()[j]);
  }
  for (std::uint32_t i = 0; i < out.n_vertices(); ++i) out.state({i}).anchor_mm = out.point_mm({i});
}

void from_plain_mesh(const Mesh& plain, BalloonMesh& out) {
  out.clear();
  for (const Vec3f& p_mm : plain.vertices) out.state(out.add_vertex(p_mm)).anchor_mm = p_mm;
  for (const auto& t : plain.triangles) {
    if (t[0] >= plain.vertices.size() || t[1] >= plain.vertices.size() ||
        t[2] >= plain.vertices.size())
      throw std::invalid_argument("from_plain_mesh: triangle index out of range");
    out.add_triangle({t[0]}, {t[1]}, {t[2]});
  }
}

int euler_characteristic(const BalloonMesh& mesh) {
  int v = 0, e = 0, f = 0;
  for (std::uint32_t i = 0; i < mesh.n_vertices(); ++i) v += !mesh.is_deleted(Vertex{i});
  for (std::uint32_t i = 0; i < mesh.n_edges(); ++i) e += !mesh.is_deleted(Edge{i});
  for (std::uint32_t i = 0; i < mesh.n_faces(); ++i) f += !mesh.is_deleted(Face{i});
  return v - e + f;
}

std::string validate(const BalloonMesh& mesh) {
  const std::uint32_t nv = mesh.n_vertices(), nh = mesh.n_halfedges(), nf = mesh.n_faces();
  auto bad_vertex = [&](Vertex v) { return !(v.idx < nv) || mesh.is_deleted(v); };
  auto bad_face = [&](Face f) { return !(f.idx < nf) || mesh.is_deleted(f); };
  auto bad_halfedge = [&](Halfedge h) { return !(h.idx < nh) || mesh.is_deleted(mesh.edge(h)); };

  // Halfedges: closed triangles, twins reversed.
  std::vector<int> outgoing(nv, 0);
  for (std::uint32_t i = 0; i < nh; ++i) {
    const Halfedge h{i};
    if (mesh.is_deleted(mesh.edge(h))) continue;
    const std::string at = " at halfedge " + std::to_string(i);
    if (bad_vertex(mesh.to_vertex(h)) || bad_vertex(mesh.from_vertex(h)))
      return "halfedge to a deleted vertex" + at;
    if (mesh.is_boundary(h)) return "boundary halfedge" + at;
    if (bad_face(mesh.face(h))) return "halfedge of a deleted face" + at;
    const Halfedge n1 = mesh.next(h);
    if (bad_halfedge(n1) || bad_halfedge(mesh.next(n1))) return "next halfedge deleted" + at;
    if (mesh.next(mesh.next(n1)) != h) return "face that is not a triangle" + at;
    if (mesh.face(n1) != mesh.face(h)) return "face loop with two faces" + at;
    if (mesh.from_vertex(n1) != mesh.to_vertex(h)) return "next does not continue" + at;
    ++outgoing[mesh.from_vertex(h).idx];
  }
  // Vertices: the rotation around the outgoing halfedge reaches all of them (manifold).
  int n_live = 0;
  for (std::uint32_t i = 0; i < nv; ++i) {
    const Vertex v{i};
    if (mesh.is_deleted(v)) continue;
    ++n_live;
    const Halfedge start = mesh.halfedge(v);
    if (!start.valid()) return "isolated vertex " + std::to_string(i);
    if (bad_halfedge(start) || mesh.from_vertex(start) != v)
      return "vertex with a wrong outgoing halfedge " + std::to_string(i);
    int around = 0;
    Halfedge h = start;
    do {
      if (++around > outgoing[i]) break;
      h = mesh.cw_rotated(h);
    } while (h != start);
    if (around != outgoing[i]) return "non-manifold vertex " + std::to_string(i);
    if (around < 3) return "vertex of valence < 3: " + std::to_string(i);
  }
  if (n_live < 4) return "fewer than 4 vertices";
  std::set<std::pair<std::uint32_t, std::uint32_t>> edges;
  for (std::uint32_t i = 0; i < mesh.n_edges(); ++i) {
    const Edge e{i};
    if (mesh.is_deleted(e)) continue;
    std::uint32_t a = mesh.from_vertex(mesh.halfedge(e, 0)).idx;
    std::uint32_t b = mesh.to_vertex(mesh.halfedge(e, 0)).idx;
    if (a == b) return "loop edge";
    if (a > b) std::swap(a, b);
    if (!edges.insert({a, b}).second) return "duplicate edge";
  }
  std::set<std::array<std::uint32_t, 3>> faces;
  double volume6 = 0.0;
  for (std::uint32_t i = 0; i < nf; ++i) {
    const Face f{i};
    if (mesh.is_deleted(f)) continue;
    const Halfedge h = mesh.halfedge(f);
    if (bad_halfedge(h) || mesh.face(h) != f) return "face with a wrong halfedge";
    std::array<std::uint32_t, 3> idx{mesh.to_vertex(h).idx, mesh.to_vertex(mesh.next(h)).idx,
                                     mesh.to_vertex(mesh.next(mesh.next(h))).idx};
    if (idx[0] == idx[1] || idx[1] == idx[2] || idx[0] == idx[2]) return "degenerate face";
    volume6 +=
        dot(mesh.point_mm({idx[0]}), cross(mesh.point_mm({idx[1]}), mesh.point_mm({idx[2]})));
    std::sort(idx.begin(), idx.end());
    if (!faces.insert(idx).second) return "duplicate face";
  }
  const int chi = n_live - static_cast<int>(edges.size()) + static_cast<int>(faces.size());
  if (chi != 2) return "Euler characteristic " + std::to_string(chi) + " != 2";
  if (!(volume6 > 0.0)) return "non-positive enclosed volume (inward oriented?)";
  return {};
}

Mesh to_plain_mesh(const BalloonMesh& mesh) {
  Mesh out;
  std::vector<std::uint32_t> index(mesh.n_vertices(), 0);
  for (std::uint32_t i = 0; i < mesh.n_vertices(); ++i) {
    if (mesh.is_deleted(Vertex{i})) continue;
    index[i] = static_cast<std::uint32_t>(out.vertices.size());
    out.vertices.push_back(mesh.point_mm({i}));
  }
  for (std::uint32_t i = 0; i < mesh.n_faces(); ++i) {
    if (mesh.is_deleted(Face{i})) continue;
    const Halfedge h = mesh.halfedge(Face{i});
    out.triangles.push_back({index[mesh.to_vertex(h).idx], index[mesh.to_vertex(mesh.next(h)).idx],
                             index[mesh.to_vertex(mesh.next(mesh.next(h))).idx]});
  }
  return out;
}

}  // namespace sonomesh::segment::internal
