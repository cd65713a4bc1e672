// The warm start's start mesh from the previous balloon's eroded interior (warm_interior.h).
//
// Why not the balloon moved inward along its normals: where the balloon met itself (behind a
// needle) two sheets lie less than a voxel apart, and the inset folds faces along that seam.
// Eroding the interior opens the seam instead: its cells are taken out of the interior with the
// surface, and the erosion widens the gap on both sides.
#include "segment/internal/warm_interior.h"

#include <openvdb/openvdb.h>
#include <openvdb/tools/VolumeToMesh.h>

#include <Eigen/Geometry>
#include <algorithm>
#include <array>
#include <cmath>
#include <cstdint>
#include <limits>
#include <numeric>
#include <stdexcept>
#include <utility>
#include <vector>

#include "mesh/parallel.h"

namespace sonomesh::segment::internal {
namespace {

using Vec3i = volume::Vec3i;
using Vec3d = Eigen::Vector3d;

// Cells round the balloon's bounding box: the parity fill and the distance transform need
// outside cells all round.
constexpr int kMarginCells = 2;
// Surface samples at most this far apart (cells), so each cell the surface crosses gets one.
constexpr float kSampleSpacingCells = 0.4f;
// An interior that kept a tunnel is eroded by up to this many cells more before giving up.
constexpr int kExtraErosionCells = 2;
constexpr float kFar = 1e20f;  // squared distance of a cell no source has reached yet

// The grid: cell (i, j, k) is centred at origin_mm + cell_mm·(i, j, k), x fastest.
struct CellBox {
  Vec3f origin_mm = Vec3f::Zero();
  float cell_mm = 1.0f;
  Vec3i dims = Vec3i::Zero();

  std::size_t size() const {
    return static_cast<std::size_t>(dims.x()) * dims.y() * static_cast<std::size_t>(dims.z());
  }
  std::size_t index(int i, int j, int k) const {
    return (static_cast<std::size_t>(k) * dims.y() + j) * dims.x() + i;
  }
  Vec3f cells(const Vec3f& p_mm) const { return (p_mm - origin_mm) / cell_mm; }
  bool contains(const Vec3i& c) const {
    return (c.array() >= 0).all() && (c.array() < dims.array()).all();
  }
};

CellBox box_around(const Mesh& m, float cell_mm) {
  const auto [lo, hi] = mesh::bounding_box(m);
  CellBox box;
  box.cell_mm = cell_mm;
  box.origin_mm = lo - Vec3f::Constant(static_cast<float>(kMarginCells) * cell_mm);
  box.dims = (((hi - lo) / cell_mm).array().ceil().cast<int>() + (2 * kMarginCells + 1)).matrix();
  return box;
}

// A row of cell centres along x at (y, z) = (j, k) crosses the triangle when (j, k) lies in its
// (y, z) shadow; on a shared edge the top-left rule counts it for one of the two triangles.
// Returns the crossing's x, or NaN.
double row_crossing(const std::array<Vec3d, 3>& p, double twice_area, int j, int k) {
  double w[3];
  for (int e = 0; e < 3; ++e) {
    const Vec3d& a = p[e];
    const Vec3d& b = p[(e + 1) % 3];
    const double dy = b.y() - a.y(), dz = b.z() - a.z();
    w[e] = dy * (k - a.z()) - dz * (j - a.y());
    const bool top_left = dz < 0.0 || (dz == 0.0 && dy < 0.0);
    if (!(w[e] > 0.0 || (w[e] == 0.0 && top_left))) return std::nan("");
  }
  return (w[0] * p[2].x() + w[1] * p[0].x() + w[2] * p[1].x()) / twice_area;
}

// Ray parity along x: a cell is inside when an odd number of crossings lie before it in its row.
std::vector<std::uint8_t> inside_cells(const Mesh& m, const CellBox& box) {
  std::vector<std::pair<int, float>> crossings;  // (row j + k·ny, x)
  crossings.reserve(2 * m.triangles.size());
  for (const auto& t : m.triangles) {
    std::array<Vec3d, 3> p;
    for (int c = 0; c < 3; ++c) p[c] = box.cells(m.vertices[t[c]]).cast<double>();
    double area = (p[1].y() - p[0].y()) * (p[2].z() - p[0].z()) -
                  (p[1].z() - p[0].z()) * (p[2].y() - p[0].y());
    if (area == 0.0) continue;  // seen edge-on: a row grazes it, which parity ignores
    if (area < 0.0) {
      std::swap(p[1], p[2]);
      area = -area;
    }
    const Vec3d lo = p[0].cwiseMin(p[1]).cwiseMin(p[2]), hi = p[0].cwiseMax(p[1]).cwiseMax(p[2]);
    for (int k = static_cast<int>(std::ceil(lo.z())); k <= static_cast<int>(hi.z()); ++k)
      for (int j = static_cast<int>(std::ceil(lo.y())); j <= static_cast<int>(hi.y()); ++j)
        if (const double x = row_crossing(p, area, j, k); !std::isnan(x))
          crossings.emplace_back(k * box.dims.y() + j, static_cast<float>(x));
  }
  std::sort(crossings.begin(), crossings.end());
  std::vector<std::uint8_t> inside(box.size(), 0);
  for (std::size_t c = 0; c + 1 < crossings.size();) {
    const auto [row, x0] = crossings[c];
    const auto [row1, x1] = crossings[c + 1];
    // A row with an odd count (a seam the parity cannot resolve) loses its last crossing.
    c += row1 == row ? 2 : 1;
    if (row1 != row) continue;
    const int i0 = std::max(0, static_cast<int>(std::ceil(x0)));
    const int i1 = std::min(box.dims.x() - 1, static_cast<int>(std::floor(x1)));
    const std::size_t base = static_cast<std::size_t>(row) * box.dims.x();
    for (int i = i0; i <= i1; ++i) inside[base + i] = 1;
  }
  return inside;
}

// Every cell the surface passes through leaves the interior, so two sheets of the balloon that
// met with less than a cell between them do not join their sides' interiors.
void take_out_surface(const Mesh& m, const CellBox& box, std::vector<std::uint8_t>& inside) {
  for (const auto& t : m.triangles) {
    const Vec3f a = box.cells(m.vertices[t[0]]), b = box.cells(m.vertices[t[1]]),
                c = box.cells(m.vertices[t[2]]);
    const float longest = std::max({(b - a).norm(), (c - a).norm(), (c - b).norm()});
    const int n = std::max(1, static_cast<int>(std::ceil(longest / kSampleSpacingCells)));
    for (int s = 0; s <= n; ++s)
      for (int r = 0; r + s <= n; ++r) {
        const Vec3f p =
            a + (b - a) * (static_cast<float>(s) / n) + (c - a) * (static_cast<float>(r) / n);
        const Vec3i cell = p.array().round().cast<int>().matrix();
        if (box.contains(cell)) inside[box.index(cell.x(), cell.y(), cell.z())] = 0;
      }
  }
}

// The squared Euclidean distance transform along one line of `n` values `stride` apart
// (Felzenszwalb and Huttenlocher 2012: the lower envelope of parabolas).
struct LineScratch {
  std::vector<float> f, z;
  std::vector<int> v;
  explicit LineScratch(int n) : f(n), z(n + 1), v(n) {}
};

void distance_line(float* line, int n, std::ptrdiff_t stride, LineScratch& s) {
  for (int q = 0; q < n; ++q) s.f[q] = line[q * stride];
  auto meet = [&](int q, int r) {
    return ((s.f[q] + static_cast<float>(q * q)) - (s.f[r] + static_cast<float>(r * r))) /
           static_cast<float>(2 * (q - r));
  };
  int k = 0;
  s.v[0] = 0;
  s.z[0] = -std::numeric_limits<float>::infinity();
  s.z[1] = std::numeric_limits<float>::infinity();
  for (int q = 1; q < n; ++q) {
    float at = meet(q, s.v[k]);
    while (at <= s.z[k]) at = meet(q, s.v[--k]);
    s.v[++k] = q;
    s.z[k] = at;
    s.z[k + 1] = std::numeric_limits<float>::infinity();
  }
  k = 0;
  for (int q = 0; q < n; ++q) {
    while (s.z[k + 1] < static_cast<float>(q)) ++k;
    const float d = static_cast<float>(q - s.v[k]);
    line[q * stride] = d * d + s.f[s.v[k]];
  }
}

// Squared distance (cells²) of every cell to the nearest cell outside the interior.
std::vector<float> squared_depth(const std::vector<std::uint8_t>& inside, const CellBox& box) {
  std::vector<float> d2(inside.size());
  for (std::size_t c = 0; c < inside.size(); ++c) d2[c] = inside[c] ? kFar : 0.0f;
  const int nx = box.dims.x(), ny = box.dims.y(), nz = box.dims.z();
  const int longest = std::max({nx, ny, nz});
  const std::ptrdiff_t sy = nx, sz = static_cast<std::ptrdiff_t>(nx) * ny;
  // Each pass's lines are independent: slabs of them on both cores (the same result).
  const int threads = mesh::default_threads();
  mesh::parallel_chunks(0, nz, threads, [&](int k0, int k1, int) {
    LineScratch s(longest);
    for (int k = k0; k < k1; ++k)
      for (int j = 0; j < ny; ++j) distance_line(&d2[box.index(0, j, k)], nx, 1, s);
    for (int k = k0; k < k1; ++k)
      for (int i = 0; i < nx; ++i) distance_line(&d2[box.index(i, 0, k)], ny, sy, s);
  });
  mesh::parallel_chunks(0, ny, threads, [&](int j0, int j1, int) {
    LineScratch s(longest);
    for (int j = j0; j < j1; ++j)
      for (int i = 0; i < nx; ++i) distance_line(&d2[box.index(i, j, 0)], nz, sz, s);
  });
  return d2;
}

// The 6-connected component of cells deeper than `min_d2` at `start`, marked in `out`; returns
// its size. (Deep cells are never on the box's border: the margin is outside.)
std::size_t component_at(const std::vector<float>& d2, float min_d2, const CellBox& box,
                         std::size_t start, std::vector<std::uint8_t>& out) {
  out.assign(d2.size(), 0);
  if (!(d2[start] > min_d2)) return 0;
  const std::ptrdiff_t step[6] = {1,
                                  -1,
                                  box.dims.x(),
                                  -box.dims.x(),
                                  static_cast<std::ptrdiff_t>(box.dims.x()) * box.dims.y(),
                                  -static_cast<std::ptrdiff_t>(box.dims.x()) * box.dims.y()};
  std::vector<std::size_t> stack{start};
  out[start] = 1;
  std::size_t count = 0;
  while (!stack.empty()) {
    const std::size_t c = stack.back();
    stack.pop_back();
    ++count;
    for (const std::ptrdiff_t s : step) {
      const std::size_t n = c + s;
      if (!out[n] && d2[n] > min_d2) {
        out[n] = 1;
        stack.push_back(n);
      }
    }
  }
  return count;
}

// The deepest cell within one cell of the seed's, else the deepest cell of the box: the erosion
// may have taken the seed's own cell (a seed near the old wall).
std::size_t start_cell(const std::vector<float>& d2, const CellBox& box, const Vec3f& seed_mm) {
  const Vec3i s = box.cells(seed_mm).array().round().cast<int>().matrix();
  std::size_t best = 0;
  float deepest = -1.0f;
  for (int dz = -1; dz <= 1; ++dz)
    for (int dy = -1; dy <= 1; ++dy)
      for (int dx = -1; dx <= 1; ++dx) {
        const Vec3i c = s + Vec3i(dx, dy, dz);
        if (!box.contains(c)) continue;
        const std::size_t i = box.index(c.x(), c.y(), c.z());
        if (d2[i] > deepest) {
          deepest = d2[i];
          best = i;
        }
      }
  if (deepest > 0.0f) return best;
  return static_cast<std::size_t>(std::max_element(d2.begin(), d2.end()) - d2.begin());
}

// The surface of the component (level `depth_cells` of the distance, the component's cells
// inside, every other cell outside): OpenVDB's mesher on the box's cells, its quads split along
// the shorter diagonal. (A band of one cell with the interior filled by signedFloodFill lost
// 40 % of the interior.)
Mesh component_surface(const std::vector<float>& d2, const std::vector<std::uint8_t>& component,
                       float depth_cells, const CellBox& box) {
  constexpr float kBand = 1.0f, kEpsilon = 1e-3f;  // values beyond ±1 cell never meet the level
  auto grid = openvdb::FloatGrid::create(kBand);
  auto transform = openvdb::math::Transform::createLinearTransform(box.cell_mm);
  transform->postTranslate(openvdb::Vec3d(box.origin_mm.x(), box.origin_mm.y(), box.origin_mm.z()));
  grid->setTransform(transform);
  auto accessor = grid->getAccessor();
  for (int k = 0; k < box.dims.z(); ++k)
    for (int j = 0; j < box.dims.y(); ++j)
      for (int i = 0; i < box.dims.x(); ++i) {
        const std::size_t c = box.index(i, j, k);
        const float level = depth_cells - std::sqrt(d2[c]);
        const float value = component[c] ? std::min(level, -kEpsilon) : std::max(level, kEpsilon);
        if (value < kBand) accessor.setValue(openvdb::Coord(i, j, k), std::max(value, -kBand));
      }
  std::vector<openvdb::Vec3s> points;
  std::vector<openvdb::Vec4I> quads;
  openvdb::tools::volumeToMesh(*grid, points, quads, 0.0);
  Mesh m;
  m.vertices.reserve(points.size());
  for (const auto& p : points) m.vertices.emplace_back(p.x(), p.y(), p.z());
  m.triangles.reserve(2 * quads.size());
  for (const auto& q : quads) {
    const auto at = [&](int c) { return m.vertices[q[c]]; };
    if ((at(0) - at(2)).squaredNorm() <= (at(1) - at(3)).squaredNorm()) {
      m.triangles.push_back({q[0], q[1], q[2]});
      m.triangles.push_back({q[0], q[2], q[3]});
    } else {
      m.triangles.push_back({q[0], q[1], q[3]});
      m.triangles.push_back({q[1], q[2], q[3]});
    }
  }
  return m;
}

double signed_volume_mm3(const Mesh& m) {
  double six_v = 0.0;
  for (const auto& t : m.triangles)
    six_v += m.vertices[t[0]].cast<double>().dot(
        m.vertices[t[1]].cast<double>().cross(m.vertices[t[2]].cast<double>()));
  return six_v / 6.0;
}

// Connected components by shared vertices (union-find).
int component_count(const Mesh& m) {
  std::vector<std::uint32_t> parent(m.vertices.size());
  std::iota(parent.begin(), parent.end(), 0u);
  auto root = [&](std::uint32_t v) {
    while (parent[v] != v) v = parent[v] = parent[parent[v]];
    return v;
  };
  for (const auto& t : m.triangles) {
    parent[root(t[1])] = root(t[0]);
    parent[root(t[2])] = root(t[0]);
  }
  int count = 0;
  for (std::uint32_t v = 0; v < parent.size(); ++v) count += parent[v] == v;
  return count;
}

// Why `m` cannot start a balloon (not one closed genus-0 manifold), empty if it can; `out`
// holds it, turned outward. (No validate(): it cost as much as the rest of the start mesh, and
// the remeshing keeps what it checks, as in every balloon.)
std::string to_start_mesh(Mesh& m, BalloonMesh& out) {
  if (m.triangles.size() < 4) return "the eroded interior has no surface";
  if (component_count(m) != 1) return "the eroded interior's surface has several parts";
  if (signed_volume_mm3(m) < 0.0)
    for (auto& t : m.triangles) std::swap(t[1], t[2]);
  try {
    from_plain_mesh(m, out);
  } catch (const std::invalid_argument& e) {
    return std::string("the eroded interior's surface is not manifold: ") + e.what();
  }
  for (std::uint32_t h = 0; h < out.n_halfedges(); ++h)
    if (out.is_boundary(Halfedge{h})) return "the eroded interior's surface is not closed";
  if (euler_characteristic(out) != 2) return "the eroded interior kept a tunnel";
  return {};
}

}  // namespace

std::string eroded_start_mesh(const Mesh& previous, const Vec3f& seed_mm, float inset_mm,
                              float cell_mm, const RemeshLimits& limits, BalloonMesh& out) {
  if (previous.vertices.size() < 4 || previous.triangles.size() < 4)
    return "the previous balloon has no surface";
  const CellBox box = box_around(previous, cell_mm);
  std::vector<std::uint8_t> inside = inside_cells(previous, box);
  take_out_surface(previous, box, inside);
  const std::vector<float> d2 = squared_depth(inside, box);
  const std::size_t start = start_cell(d2, box, seed_mm);
  std::vector<std::uint8_t> component;
  std::string why;
  for (int extra = 0; extra <= kExtraErosionCells; ++extra) {
    const float depth_cells = inset_mm / cell_mm + static_cast<float>(extra);
    if (component_at(d2, depth_cells * depth_cells, box, start, component) == 0)
      return "nothing of the previous balloon's interior is " + std::to_string(inset_mm) +
             " mm deep";
    Mesh m = component_surface(d2, component, depth_cells, box);
    why = to_start_mesh(m, out);
    if (!why.empty()) continue;
    remesh(out, limits);  // one pass: the evolution's remeshing does the rest
    return {};
  }
  return why;
}

}  // namespace sonomesh::segment::internal
