// Label volume from a closed mesh by ray parity along x, one ray per (j, k) row of voxel centres.

#include <algorithm>
#include <cmath>

#include "mesh/parallel.h"
#include "reconstruct/reconstruct.h"

namespace sonomesh::reconstruct {

volume::Volume rasterize_labels(const Mesh& mesh, const volume::Volume& like) {
  for (const auto& t : mesh.triangles)
    for (auto v : t)
      if (v >= mesh.vertices.size())
        throw std::invalid_argument("rasterize_labels: triangle index out of range");
  const auto dims = like.dims();
  if ((dims.array() <= 0).any()) throw std::invalid_argument("rasterize_labels: `like` is empty");
  volume::Volume labels(dims, like.spacing_mm(), like.origin_mm(), volume::VoxelType::UInt8);
  const int nx = dims.x(), ny = dims.y(), nz = dims.z();
  // Rays run a tiny irrational fraction of a voxel off the centres, so a vertex or an edge on a
  // row of centres (common: meshes and grids share round numbers) is never hit exactly.
  const double dy = 1.0e-4 * std::sqrt(2.0), dz = 1.0e-4 * std::sqrt(3.0);

  // Vertices in index space (x as a continuous index, y and z shifted by the jitter).
  std::vector<Eigen::Vector3d> v(mesh.vertices.size());
  for (std::size_t i = 0; i < v.size(); ++i) {
    const Vec3f u = like.mm_to_index(mesh.vertices[i]);
    v[i] = Eigen::Vector3d(u.x(), u.y() - dy, u.z() - dz);
  }
  // Bucket triangles by the rows their (y, z) shadow covers (CSR).
  const std::size_t rows = std::size_t(ny) * nz;
  std::vector<std::uint32_t> start(rows + 1, 0);
  auto row_range = [&](const std::array<std::uint32_t, 3>& t, int* j0, int* j1, int* k0, int* k1) {
    double ylo = v[t[0]].y(), yhi = ylo, zlo = v[t[0]].z(), zhi = zlo;
    for (int c = 1; c < 3; ++c) {
      ylo = std::min(ylo, v[t[c]].y());
      yhi = std::max(yhi, v[t[c]].y());
      zlo = std::min(zlo, v[t[c]].z());
      zhi = std::max(zhi, v[t[c]].z());
    }
    *j0 = std::max(0, int(std::ceil(ylo)));
    *j1 = std::min(ny - 1, int(std::floor(yhi)));
    *k0 = std::max(0, int(std::ceil(zlo)));
    *k1 = std::min(nz - 1, int(std::floor(zhi)));
  };
  int j0, j1, k0, k1;
  for (const auto& t : mesh.triangles) {
    row_range(t, &j0, &j1, &k0, &k1);
    for (int k = k0; k <= k1; ++k)
      for (int j = j0; j <= j1; ++j) ++start[std::size_t(k) * ny + j + 1];
  }
  for (std::size_t r = 0; r < rows; ++r) start[r + 1] += start[r];
  std::vector<std::uint32_t> fill(start.begin(), start.end() - 1), bucket(start[rows]);
  for (std::uint32_t f = 0; f < mesh.triangles.size(); ++f) {
    row_range(mesh.triangles[f], &j0, &j1, &k0, &k1);
    for (int k = k0; k <= k1; ++k)
      for (int j = j0; j <= j1; ++j) bucket[fill[std::size_t(k) * ny + j]++] = f;
  }

  auto& out = labels.u8();
  mesh::parallel_chunks(0, nz, mesh::default_threads(), [&](int kb, int ke, int) {
    std::vector<double> hits;
    for (int k = kb; k < ke; ++k)
      for (int j = 0; j < ny; ++j) {
        const std::size_t r = std::size_t(k) * ny + j;
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
