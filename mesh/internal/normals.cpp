// Oriented vertex samples: normals of equation (2) and one-third-area weights.
#include <Eigen/Geometry>
#include <array>
#include <cstdint>
#include <stdexcept>
#include <string>

#include "mesh/mesh.h"

namespace sonomesh::mesh {
namespace {

void check_mesh(const Mesh& mesh, const char* who) {
  for (const auto& t : mesh.triangles)
    for (auto v : t)
      if (v >= mesh.vertices.size())
        throw std::invalid_argument(std::string(who) + ": triangle index " + std::to_string(v) +
                                    " out of range (" + std::to_string(mesh.vertices.size()) +
                                    " vertices)");
}

// Twice the triangle's area, and its unit normal (zero when it is degenerate).
float unit_normal(const Mesh& mesh, const std::array<std::uint32_t, 3>& tri, Vec3f& unit) {
  const Vec3f& a = mesh.vertices[tri[0]];
  const Vec3f cross = (mesh.vertices[tri[1]] - a).cross(mesh.vertices[tri[2]] - a);
  const float len = cross.norm();
  unit = len > 0.0f ? Vec3f(cross / len) : Vec3f::Zero();
  return len;
}

}  // namespace

// A vertex's normal is the normalised sum of the unit normals of its kept triangles, so a vertex
// at the rim of an opening gets its normal from the triangles that remain; its weight is a third
// of their area.
PointCloud oriented_samples(const Mesh& mesh, const std::vector<char>& keep,
                            const std::vector<char>& drop_vertex) {
  check_mesh(mesh, "oriented_samples");
  const std::size_t nv = mesh.vertices.size();
  if (keep.size() != mesh.triangles.size() || drop_vertex.size() != nv)
    throw std::invalid_argument(
        "oriented_samples: keep_triangle and drop_vertex must match the mesh's triangles and "
        "vertices");
  std::vector<Vec3f> normal_sum(nv, Vec3f::Zero());
  std::vector<float> area(nv, 0.0f);
  std::vector<char> touched(nv, 0);
  for (std::size_t t = 0; t < mesh.triangles.size(); ++t) {
    if (!keep[t]) continue;
    const auto& tri = mesh.triangles[t];
    Vec3f unit;
    const float len = unit_normal(mesh, tri, unit);
    for (auto v : tri) {
      touched[v] = 1;
      area[v] += len / 6.0f;  // triangle area / 3
      normal_sum[v] += unit;
    }
  }
  PointCloud out;
  for (std::size_t v = 0; v < nv; ++v) {
    if (drop_vertex[v] || !touched[v]) continue;
    const float len = normal_sum[v].norm();
    if (!(len > 0.0f)) continue;  // only degenerate triangles around it: no direction to give
    out.points.push_back(mesh.vertices[v]);
    out.normals.push_back(normal_sum[v] / len);
    out.area_mm2.push_back(area[v]);
  }
  return out;
}

std::vector<Vec3f> vertex_normals(const Mesh& mesh) {
  check_mesh(mesh, "vertex_normals");
  std::vector<Vec3f> normal(mesh.vertices.size(), Vec3f::Zero());
  for (const auto& tri : mesh.triangles) {
    Vec3f unit;
    unit_normal(mesh, tri, unit);
    for (auto v : tri) normal[v] += unit;
  }
  for (Vec3f& n : normal)
    if (n.norm() > 0.0f) n.normalize();
  return normal;
}

PointCloud oriented_samples(const Mesh& mesh) {
  check_mesh(mesh, "oriented_samples");
  return oriented_samples(mesh, std::vector<char>(mesh.triangles.size(), 1),
                          std::vector<char>(mesh.vertices.size(), 0));
}

}  // namespace sonomesh::mesh
