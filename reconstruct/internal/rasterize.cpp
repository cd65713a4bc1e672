// Label volume from a closed mesh by ray parity along x, one ray per (j, k) row of voxel centres.

#include <algorithm>
#include <cmath>
#include <limits>

#include "mesh/parallel.h"
#include "reconstruct/reconstruct.h"

namespace sonomesh::reconstruct {

namespace {

// The mesh's vertices in index space (x as a continuous index, y and z shifted by the jitter)
// and the box of (j, k) rows their (y, z) shadow covers, clamped to the grid.
struct IndexMesh {
  std::vector<Eigen::Vector3d> v;
  int jb = 0, je = -1, kb = 0, ke = -1;
};

IndexMesh to_index_space(const Mesh& mesh, const volume::Volume& like) {
  // Rays run a tiny irrational fraction of a voxel off the centres, so a vertex or an edge on a
  // row of centres (common: meshes and grids share round numbers) is never hit exactly.
  const double dy = 1.0e-4 * std::sqrt(2.0), dz = 1.0e-4 * std::sqrt(3.0);
  IndexMesh im;
  im.v.resize(mesh.vertices.size());
  if (im.v.empty()) return im;
  Eigen::Vector3d lo = Eigen::Vector3d::Constant(std::numeric_limits<double>::max()), hi = -lo;
  for (std::size_t i = 0; i < im.v.size(); ++i) {
    const Vec3f u = like.mm_to_index(mesh.vertices[i]);
    im.v[i] = Eigen::Vector3d(u.x(), u.y() - dy, u.z() - dz);
    lo = lo.cwiseMin(im.v[i]);
    hi = hi.cwiseMax(im.v[i]);
  }
  // Only the rows of this box are visited: a target is a small part of the volume, and the rows
  // outside it, one per (j, k) of the grid, would only be found empty.
  im.jb = std::max(0, int(std::ceil(lo.y())));
  im.je = std::min(like.dims().y() - 1, int(std::floor(hi.y())));
  im.kb = std::max(0, int(std::ceil(lo.z())));
  im.ke = std::min(like.dims().z() - 1, int(std::floor(hi.z())));
  return im;
}

}  // namespace

volume::Volume rasterize_labels(const Mesh& mesh, const volume::Volume& like) {
  for (const auto& t : mesh.triangles)
    for (auto v : t)
      if (v >= mesh.vertices.size())
        throw std::invalid_argument("rasterize_labels: triangle index out of range");
  const auto dims = like.dims();
  if ((dims.array() <= 0).any()) throw std::invalid_argument("rasterize_labels: `like` is empty");
  volume::Volume labels(dims, like.spacing_mm(), like.origin_mm(), volume::VoxelType::UInt8);
  const int nx = dims.x();
  const IndexMesh im = to_index_space(mesh, like);
  const std::vector<Eigen::Vector3d>& v = im.v;
  const int jb = im.jb, je = im.je, kb = im.kb, ke = im.ke;
  if (mesh.triangles.empty() || jb > je || kb > ke) return labels;
  const int box_ny = je - jb + 1;
  auto row_of = [&](int j, int k) { return std::size_t(k - kb) * box_ny + (j - jb); };
  // Bucket triangles by the rows their (y, z) shadow covers (CSR).
  const std::size_t rows = std::size_t(box_ny) * (ke - kb + 1);
  std::vector<std::uint32_t> start(rows + 1, 0);
  auto row_range = [&](const std::array<std::uint32_t, 3>& t, int* j0, int* j1, int* k0, int* k1) {
    double ylo = v[t[0]].y(), yhi = ylo, zlo = v[t[0]].z(), zhi = zlo;
    for (int c = 1; c < 3; ++c) {
      ylo = std::min(ylo, v[t[c]].y());
      yhi = std::max(yhi, v[t[c]].y());
      zlo = std::min(zlo, v[t[c]].z());
      zhi = std::max(zhi, v[t[c]].z());
    }
    *j0 = std::max(jb, int(std::ceil(ylo)));
    *j1 = std::min(je, int(std::floor(yhi)));
    *k0 = std::max(kb, int(std::ceil(zlo)));
    *k1 = std::min(ke, int(std::floor(zhi)));
  };
  int j0, j1, k0, k1;
  for (const auto& t : mesh.triangles) {
    row_range(t, &j0, &j1, &k0, &k1);
    for (int k = k0; k <= k1; ++k)
      for (int j = j0; j <= j1; ++j) ++start[row_of(j, k) + 1];
  }
  for (std::size_t r = 0; r < rows; ++r) start[r + 1] += start[r];
  std::vector<std::uint32_t> fill(start.begin(), start.end() - 1), bucket(start[rows]);
  for (std::uint32_t f = 0; f < mesh.triangles.size(); ++f) {
    row_range(mesh.triangles[f], &j0, &j1, &k0, &k1);
    for (int k = k0; k <= k1; ++k)
      for (int j = j0; j <= j1; ++j) bucket[fill[row_of(j, k)]++] = f;
  }

  auto& out = labels.u8();
  mesh::parallel_chunks(kb, ke + 1, mesh::default_threads(), [&](int k_begin, int k_end, int) {
    std::vector<double> hits;
    for (int k = k_begin; k < k_end; ++k)
      for (int j = jb; j <= je; ++j) {
        const std::size_t r = row_of(j, k);
        hits.clear();
        for (auto b = start[r]; b < start[r + 1]; ++b) {
          const auto& t = mesh.triangles[bucket[b]];
          const Eigen::Vector3d &a = v[t[0]], &p = v[t[1]], &q = v[t[2]];
          // Barycentric coordinates of (j, k) in the triangle's (y, z) shadow.
          const double det = (p.y() - a.y()) * (q.z() - a.z()) - (q.y() - a.y()) * (p.z() - a.z());
          if (det == 0.0) continue;  // edge-on: the neighbours account for the crossing
          const double s = ((j - a.y()) * (q.z() - a.z()) - (q.y() - a.y()) * (k - a.z())) / det;
          const double w = ((p.y() - a.y()) * (k - a.z()) - (j - a.y()) * (p.z() - a.z())) / det;
          if (s < 0.0 || w < 0.0 || s + w > 1.0) continue;
          hits.push_back(a.x() + s * (p.x() - a.x()) + w * (q.x() - a.x()));
        }
        if (hits.size() < 2) continue;
        std::sort(hits.begin(), hits.end());
        for (std::size_t h = 0; h + 1 < hits.size(); h += 2) {
          const int i0 = std::max(0, int(std::ceil(hits[h])));
          const int i1 = std::min(nx - 1, int(std::floor(hits[h + 1])));
          for (int i = i0; i <= i1; ++i) out[labels.linear_index(i, j, k)] = 1;
        }
      }
  });
  return labels;
}

}  // namespace sonomesh::reconstruct
