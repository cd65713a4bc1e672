// Marching cubes (Lorensen & Cline 1987) with a case table generated here rather than typed in.
//
// Why generated: the published 256-case tables resolve ambiguous faces by sign pattern only and
// reuse one triangulation for a case and its complement, which is what leaves holes between
// neighbouring cubes. Here a case is the 8 corner signs plus, for each ambiguous face, the
// asymptotic decider's answer (Nielson & Hamann 1991) - 2^14 keys. The decider depends only on
// the face's four values, so the two cubes sharing a face always draw the same segments on it:
// the mesh is watertight by construction. Each cube's face segments are chained into closed
// loops and every loop is triangulated as a fan whose diagonals never join two vertices of one
// cube face (otherwise a diagonal could be shared with the neighbour cube and an edge would get
// four triangles); a loop that admits no such fan gets a centre vertex. So every mesh edge lies
// either on a cube face (exactly two cubes, one triangle each) or inside one cube (exactly two
// triangles of one fan): a closed 2-manifold.

#include <array>
#include <cassert>
#include <cmath>
#include <cstdint>
#include <memory>
#include <stdexcept>
#include <vector>

#include "mesh/parallel.h"
#include "reconstruct/reconstruct.h"

namespace sonomesh::reconstruct {
namespace {

// Corner c of a cube sits at (c & 1, (c >> 1) & 1, (c >> 2) & 1). Edge e runs along axis e / 4
// from corner kEdgeBase[e] to kEdgeBase[e] + (1 << axis).
constexpr std::array<int, 12> kEdgeBase = {0, 2, 4, 6, 0, 1, 4, 5, 0, 1, 2, 3};

int edge_axis(int e) { return e / 4; }
int edge_end(int e) { return kEdgeBase[e] + (1 << edge_axis(e)); }

int edge_between(int c0, int c1) {
  for (int e = 0; e < 12; ++e) {
    if ((kEdgeBase[e] == c0 && edge_end(e) == c1) || (kEdgeBase[e] == c1 && edge_end(e) == c0))
      return e;
  }
  assert(false && "corners are not adjacent");
  return -1;
}

struct Face {
  int axis = 0, side = 0;
  std::array<int, 4> corners{};  // cyclic order
  std::array<int, 4> edges{};    // edges[i] joins corners[i] and corners[i + 1]
};

std::array<Face, 6> make_faces() {
  std::array<Face, 6> faces{};
  for (int f = 0; f < 6; ++f) {
    Face& face = faces[f];
    face.axis = f / 2;
    face.side = f % 2;
    const int u = (face.axis + 1) % 3, v = (face.axis + 2) % 3;
    const int uv[4][2] = {{0, 0}, {1, 0}, {1, 1}, {0, 1}};
    for (int i = 0; i < 4; ++i)
      face.corners[i] = (face.side << face.axis) | (uv[i][0] << u) | (uv[i][1] << v);
    for (int i = 0; i < 4; ++i)
      face.edges[i] = edge_between(face.corners[i], face.corners[(i + 1) % 4]);
  }
  return faces;
}

const std::array<Face, 6>& faces() {
  static const std::array<Face, 6> f = make_faces();
  return f;
}

std::array<float, 3> corner_pos(int c) {
  return {float(c & 1), float((c >> 1) & 1), float((c >> 2) & 1)};
}
std::array<float, 3> edge_mid(int e) {
  auto p = corner_pos(kEdgeBase[e]);
  p[edge_axis(e)] = 0.5f;
  return p;
}

bool edges_share_face(int e0, int e1) {
  for (const Face& f : faces()) {
    bool a = false, b = false;
    for (int e : f.edges) {
      a |= e == e0;
      b |= e == e1;
    }
    if (a && b) return true;
  }
  return false;
}

bool face_ambiguous(const Face& f, int mask) {
  const int s0 = (mask >> f.corners[0]) & 1, s1 = (mask >> f.corners[1]) & 1;
  const int s2 = (mask >> f.corners[2]) & 1, s3 = (mask >> f.corners[3]) & 1;
  return s0 == s2 && s1 == s3 && s0 != s1;
}

// Vertex ids in a case: 0..11 are edge crossings, 12 + n is the centre of centre loop n.
struct Case {
  std::vector<std::array<std::uint8_t, 3>> triangles;
  std::vector<std::vector<std::uint8_t>> centre_loops;  // edge ids of loops with a centre vertex
};

Case build_case(int mask, int decisions) {
  const auto& fs = faces();
  std::array<int, 12> next;
  next.fill(-1);
  auto add_segment = [&](int p, int q, int ref_corner, const Face& f) {
    // Orient p -> q so that, seen from outside the cube, the inside corners lie on the right;
    // chained loops are then counter-clockwise seen from the outside (the low-field side).
    const auto a = edge_mid(p), b = edge_mid(q), x = corner_pos(ref_corner);
    const float d[3] = {b[0] - a[0], b[1] - a[1], b[2] - a[2]};
    const float r[3] = {x[0] - a[0], x[1] - a[1], x[2] - a[2]};
    const float cr[3] = {d[1] * r[2] - d[2] * r[1], d[2] * r[0] - d[0] * r[2],
                         d[0] * r[1] - d[1] * r[0]};
    const float o = cr[f.axis] * (f.side ? 1.0f : -1.0f);
    const bool ref_inside = (mask >> ref_corner) & 1;
    if ((ref_inside && o > 0) || (!ref_inside && o < 0)) std::swap(p, q);
    assert(next[p] == -1);
    next[p] = q;
  };
  for (int fi = 0; fi < 6; ++fi) {
    const Face& f = fs[fi];
    int in[4];
    for (int i = 0; i < 4; ++i) in[i] = (mask >> f.corners[i]) & 1;
    int crossing[4], n = 0;
    for (int i = 0; i < 4; ++i)
      if (in[i] != in[(i + 1) % 4]) crossing[n++] = i;
    if (n == 2) {
      add_segment(f.edges[crossing[0]], f.edges[crossing[1]], f.corners[(crossing[0] + 1) % 4], f);
    } else if (n == 4) {
      // Inside connected across the face: the segments cut off the outside corners, else the
      // inside ones.
      const int cut = ((decisions >> fi) & 1) ? 0 : 1;
      for (int i = 0; i < 4; ++i)
        if (in[i] == cut) add_segment(f.edges[(i + 3) % 4], f.edges[i], f.corners[i], f);
    }
  }
  Case c;
  std::array<bool, 12> used{};
  for (int start = 0; start < 12; ++start) {
    if (next[start] < 0 || used[start]) continue;
    std::vector<std::uint8_t> loop;
    for (int e = start; !used[e]; e = next[e]) {
      assert(next[e] >= 0);
      used[e] = true;
      loop.push_back(static_cast<std::uint8_t>(e));
    }
    const int n = static_cast<int>(loop.size());
    assert(n >= 3);
    int apex = -1;
    for (int a = 0; a < n && apex < 0; ++a) {
      bool ok = true;
      for (int k = 2; k <= n - 2 && ok; ++k) ok = !edges_share_face(loop[a], loop[(a + k) % n]);
      if (ok) apex = a;
    }
    if (apex >= 0) {
      for (int k = 1; k + 1 < n; ++k)
        c.triangles.push_back({loop[apex], loop[(apex + k) % n], loop[(apex + k + 1) % n]});
    } else {
      const auto centre = static_cast<std::uint8_t>(12 + c.centre_loops.size());
      for (int k = 0; k < n; ++k) c.triangles.push_back({centre, loop[k], loop[(k + 1) % n]});
      c.centre_loops.push_back(loop);
    }
  }
  return c;
}

struct Tables {
  std::vector<Case> cases;                    // index: mask | decisions << 8
  std::array<std::uint8_t, 256> ambiguous{};  // bit f: face f is ambiguous for this mask
};

const Tables& tables() {
  static const Tables t = [] {
    Tables t;
    t.cases.resize(1 << 14);
    for (int mask = 0; mask < 256; ++mask) {
      for (int f = 0; f < 6; ++f)
        if (face_ambiguous(faces()[f], mask))
          t.ambiguous[mask] |= static_cast<std::uint8_t>(1 << f);
      for (int d = 0; d < 64; ++d) {
        if ((d & ~t.ambiguous[mask]) != 0) continue;  // only decisions for ambiguous faces matter
        t.cases[mask | (d << 8)] = build_case(mask, d);
      }
    }
    return t;
  }();
  return t;
}

// The field as marching cubes reads it: values relative to iso, inside flags, and per x-row
// whether the row is all outside (0), all inside (1) or mixed (2), so whole rows far from the
// surface are skipped.
struct McField {
  int nx = 0, ny = 0, nz = 0;
  std::size_t sy = 0, sz = 0, n_points = 0;
  const float* f = nullptr;
  float iso = 0;
  std::vector<std::uint8_t> inside, row_state;

  // Border samples count as outside (value pushed just below iso) so every surface closes.
  float value(int i, int j, int k) const {
    const float v = f[i + j * sy + k * sz] - iso;
    const bool border = i == 0 || j == 0 || k == 0 || i == nx - 1 || j == ny - 1 || k == nz - 1;
    return border ? std::min(v, -1e-30f) : v;
  }
  int state(int j, int k) const { return row_state[j + std::size_t(ny) * k]; }
  // Can the edges between row (j, k) and row (j2, k2) cross the surface?
  bool rows_differ(int j, int k, int j2, int k2) const {
    const int a = state(j, k), b = state(j2, k2);
    return a == 2 || b == 2 || a != b;
  }
  // Visits the crossed edges leaving the points of row (j, k): fn(i, axis).
  template <class Fn>
  void for_crossed_edges(int j, int k, Fn&& fn) const {
    const std::uint8_t* row = &inside[j * sy + k * sz];
    if (state(j, k) == 2)
      for (int i = 0; i + 1 < nx; ++i)
        if (row[i] != row[i + 1]) fn(i, 0);
    if (j + 1 < ny && rows_differ(j, k, j + 1, k))
      for (int i = 0; i < nx; ++i)
        if (row[i] != row[i + sy]) fn(i, 1);
    if (k + 1 < nz && rows_differ(j, k, j, k + 1))
      for (int i = 0; i < nx; ++i)
        if (row[i] != row[i + sz]) fn(i, 2);
  }
};

void classify(McField& g, int threads) {
  g.inside.resize(g.n_points);
  g.row_state.resize(std::size_t(g.ny) * g.nz);
  mesh::parallel_chunks(0, g.nz, threads, [&](int k0, int k1, int) {
    for (int k = k0; k < k1; ++k)
      for (int j = 0; j < g.ny; ++j) {
        std::uint8_t* row = &g.inside[j * g.sy + k * g.sz];
        const float* frow = g.f + j * g.sy + k * g.sz;
        int count = 0;
        if (j == 0 || k == 0 || j == g.ny - 1 || k == g.nz - 1) {
          std::fill(row, row + g.nx, std::uint8_t{0});  // border rows are outside
        } else {
          // Plain compare loop (vectorises); the two border samples of the row are outside.
          for (int i = 1; i + 1 < g.nx; ++i) row[i] = frow[i] > g.iso;
          row[0] = row[g.nx - 1] = 0;
          for (int i = 1; i + 1 < g.nx; ++i) count += row[i];
        }
        g.row_state[j + std::size_t(g.ny) * k] = count == 0 ? 0 : (count == g.nx ? 1 : 2);
      }
  });
}

// One vertex per crossed grid edge, numbered layer by layer so the threads need no locking.
// Returns the edge -> vertex index, left uninitialised: only crossed edges are ever read.
std::unique_ptr<std::int32_t[]> place_vertices(const McField& g, const volume::Volume& field,
                                               int threads, Mesh& mesh) {
  std::unique_ptr<std::int32_t[]> edge_vertex(new std::int32_t[3 * g.n_points]);
  std::vector<int> layer_count(g.nz, 0);
  mesh::parallel_chunks(0, g.nz, threads, [&](int k0, int k1, int) {
    for (int k = k0; k < k1; ++k) {
      int count = 0;
      for (int j = 0; j < g.ny; ++j) g.for_crossed_edges(j, k, [&](int, int) { ++count; });
      layer_count[k] = count;
    }
  });
  std::vector<int> layer_offset(g.nz + 1, 0);
  for (int k = 0; k < g.nz; ++k) layer_offset[k + 1] = layer_offset[k] + layer_count[k];
  mesh.vertices.resize(layer_offset[g.nz]);
  const Vec3f spacing = field.spacing_mm(), origin = field.origin_mm();
  mesh::parallel_chunks(0, g.nz, threads, [&](int k0, int k1, int) {
    for (int k = k0; k < k1; ++k) {
      int index = layer_offset[k];
      for (int j = 0; j < g.ny; ++j)
        g.for_crossed_edges(j, k, [&](int i, int a) {
          const float f0 = g.value(i, j, k);
          const float f1 = g.value(i + (a == 0), j + (a == 1), k + (a == 2));
          float t = f0 / (f0 - f1);
          t = std::isfinite(t) ? std::clamp(t, 0.0f, 1.0f) : 0.5f;
          Vec3f ijk{float(i), float(j), float(k)};
          ijk[a] += t;
          mesh.vertices[index] = origin + spacing.cwiseProduct(ijk);
          edge_vertex[3 * (i + j * g.sy + k * g.sz) + a] = index++;
        });
    }
  });
  return edge_vertex;
}

// Asymptotic decider (Nielson & Hamann) on the ambiguous faces of cell (i, j, k): bit f is set
// when face f's bilinear saddle is inside, i.e. the product of the inside diagonal exceeds that of
// the outside one. Same four floats in both cubes and multiplication commutes exactly, so the
// neighbours agree bit for bit.
int face_decisions(const McField& g, int amb, int mask, int i, int j, int k) {
  int decisions = 0;
  for (int fi = 0; fi < 6; ++fi) {
    if (!((amb >> fi) & 1)) continue;
    const Face& face = faces()[fi];
    float v[4];
    for (int q = 0; q < 4; ++q) {
      const int c = face.corners[q];
      v[q] = g.value(i + (c & 1), j + ((c >> 1) & 1), k + ((c >> 2) & 1));
    }
    const bool c0_inside = (mask >> face.corners[0]) & 1;
    const float p_in = c0_inside ? v[0] * v[2] : v[1] * v[3];
    const float p_out = c0_inside ? v[1] * v[3] : v[0] * v[2];
    if (p_in > p_out) decisions |= 1 << fi;
  }
  return decisions;
}

// One thread's triangles; centre vertices are tagged and numbered after all edge vertices.
struct McLocal {
  std::vector<std::array<std::uint32_t, 3>> triangles;
  std::vector<Vec3f> centres;
};
constexpr std::uint32_t kCentreTag = 0x80000000u;

// The triangles of cell (i, j, k), whose corner mask is neither empty nor full.
void emit_cell(const McField& g, const std::int32_t* edge_vertex, const Mesh& mesh, int mask, int i,
               int j, int k, McLocal& out) {
  const Tables& tab = tables();
  const std::size_t p = i + j * g.sy + k * g.sz;
  const std::size_t step[3] = {1, g.sy, g.sz};
  const int amb = tab.ambiguous[mask];
  const int decisions = amb ? face_decisions(g, amb, mask, i, j, k) : 0;
  const Case& cs = tab.cases[mask | (decisions << 8)];
  std::uint32_t vid[16];
  for (int e = 0; e < 12; ++e) {
    const int b = kEdgeBase[e];
    const std::size_t q = p + (b & 1) + ((b >> 1) & 1) * g.sy + ((b >> 2) & 1) * g.sz;
    if (g.inside[q] != g.inside[q + step[edge_axis(e)]])
      vid[e] = static_cast<std::uint32_t>(edge_vertex[3 * q + edge_axis(e)]);
  }
  for (std::size_t l = 0; l < cs.centre_loops.size(); ++l) {
    Vec3f c = Vec3f::Zero();
    for (auto e : cs.centre_loops[l]) c += mesh.vertices[vid[e]];
    out.centres.push_back(c / float(cs.centre_loops[l].size()));
    vid[12 + l] = kCentreTag | static_cast<std::uint32_t>(out.centres.size() - 1);
  }
  for (const auto& tri : cs.triangles)
    out.triangles.push_back({vid[tri[0]], vid[tri[1]], vid[tri[2]]});
}

// The cells of the row of cells between rows (j, k), (j + 1, k), (j, k + 1) and (j + 1, k + 1).
void emit_cell_row(const McField& g, const std::int32_t* edge_vertex, const Mesh& mesh, int j,
                   int k, McLocal& out) {
  const int s0 = g.state(j, k);
  if (s0 != 2 && s0 == g.state(j + 1, k) && s0 == g.state(j, k + 1) && s0 == g.state(j + 1, k + 1))
    return;  // the four rows around this row of cells agree everywhere: no surface
  // Corner c = cx + 2 cy + 4 cz: the four rows give bits 0, 2, 4, 6 at x and 1, 3, 5, 7 at x + 1.
  const std::uint8_t* r00 = &g.inside[j * g.sy + k * g.sz];
  const std::uint8_t* r10 = r00 + g.sy;
  const std::uint8_t* r01 = r00 + g.sz;
  const std::uint8_t* r11 = r00 + g.sy + g.sz;
  int column = r00[0] | r10[0] << 2 | r01[0] << 4 | r11[0] << 6;
  for (int i = 0; i + 1 < g.nx; ++i) {
    const int next = r00[i + 1] | r10[i + 1] << 2 | r01[i + 1] << 4 | r11[i + 1] << 6;
    const int mask = column | next << 1;
    column = next;
    if (mask != 0 && mask != 255) emit_cell(g, edge_vertex, mesh, mask, i, j, k, out);
  }
}

// Appends each thread's triangles and centre vertices to the mesh, in thread order.
void merge_locals(const std::vector<McLocal>& locals, Mesh& mesh) {
  std::size_t n_tri = 0;
  for (const auto& l : locals) n_tri += l.triangles.size();
  mesh.triangles.reserve(n_tri);
  for (const auto& l : locals) {
    const auto base = static_cast<std::uint32_t>(mesh.vertices.size());
    for (auto tri : l.triangles) {
      for (auto& v : tri)
        if (v & kCentreTag) v = base + (v & ~kCentreTag);
      mesh.triangles.push_back(tri);
    }
    mesh.vertices.insert(mesh.vertices.end(), l.centres.begin(), l.centres.end());
  }
}

}  // namespace

Mesh marching_cubes(const volume::Volume& field, float iso) {
  if (field.type() != volume::VoxelType::Float32)
    throw std::invalid_argument("marching_cubes: field must be a Float32 volume");
  const auto dims = field.dims();
  if ((dims.array() < 2).any())
    throw std::invalid_argument("marching_cubes: field needs at least 2 samples per axis");
  tables();  // built once, before the threads read it
  McField g;
  g.nx = dims.x(), g.ny = dims.y(), g.nz = dims.z();
  g.sy = static_cast<std::size_t>(g.nx), g.sz = g.sy * g.ny;
  g.n_points = g.sz * g.nz;
  g.f = field.f32().data();
  g.iso = iso;
  // Thread start-up costs more than a small grid's whole run.
  const int threads = g.n_points < (1u << 15) ? 1 : mesh::default_threads();
  classify(g, threads);
  Mesh mesh;
  const std::unique_ptr<std::int32_t[]> edge_vertex = place_vertices(g, field, threads, mesh);
  std::vector<McLocal> locals(threads);
  mesh::parallel_chunks(0, g.nz - 1, threads, [&](int k0, int k1, int t) {
    for (int k = k0; k < k1; ++k)
      for (int j = 0; j + 1 < g.ny; ++j) emit_cell_row(g, edge_vertex.get(), mesh, j, k, locals[t]);
  });
  merge_locals(locals, mesh);
  return mesh;
}

}  // namespace sonomesh::reconstruct
