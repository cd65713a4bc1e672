// Opening the balloon (method.md §4; paper §4, steps [1]-[3]) and plain vertex samples.

#include <Eigen/Geometry>
#include <stdexcept>
#include <string>

#include "reconstruct/reconstruct.h"

namespace sonomesh::reconstruct {
namespace {

// Samples from the triangles with keep[t] set, skipping vertices with drop_vertex[v] set. A
// vertex's normal is the normalised sum of the unit normals of its kept triangles (eq. 2), so a
// vertex at the rim of the opening gets its normal from the triangles that remain, as step [2]
// asks; its weight is a third of their area.
PointCloud samples_from(const Mesh& mesh, const std::vector<char>& keep,
                        const std::vector<char>& drop_vertex) {
  const std::size_t nv = mesh.vertices.size();
  std::vector<Vec3f> normal_sum(nv, Vec3f::Zero());
  std::vector<float> area(nv, 0.0f);
  std::vector<char> touched(nv, 0);
  for (std::size_t t = 0; t < mesh.triangles.size(); ++t) {
    if (!keep[t]) continue;
    const auto& tri = mesh.triangles[t];
    const Vec3f& a = mesh.vertices[tri[0]];
    const Vec3f cross = (mesh.vertices[tri[1]] - a).cross(mesh.vertices[tri[2]] - a);
    const float len = cross.norm();
    for (auto v : tri) {
      touched[v] = 1;
      area[v] += len / 6.0f;  // triangle area / 3
      if (len > 0.0f) normal_sum[v] += cross / len;
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

void check_mesh(const Mesh& mesh, const char* who) {
  for (const auto& t : mesh.triangles)
    for (auto v : t)
      if (v >= mesh.vertices.size())
        throw std::invalid_argument(std::string(who) + ": triangle index " + std::to_string(v) +
                                    " out of range (" + std::to_string(mesh.vertices.size()) +
                                    " vertices)");
}

}  // namespace

PointCloud open_balloon(const Mesh& balloon, const std::vector<StopReason>& stop) {
  if (stop.size() != balloon.vertices.size())
    throw std::invalid_argument("open_balloon: stop.size() (" + std::to_string(stop.size()) +
                                ") != balloon.vertices.size() (" +
                                std::to_string(balloon.vertices.size()) + ")");
  check_mesh(balloon, "open_balloon");
  // [1] Type-1 vertices and the triangles that touch them.
  std::vector<char> type1(balloon.vertices.size(), 0);
  for (std::size_t v = 0; v < stop.size(); ++v) type1[v] = stop[v] == StopReason::SelfIntersection;
  std::vector<char> keep(balloon.triangles.size(), 1);
  for (std::size_t t = 0; t < balloon.triangles.size(); ++t)
    for (auto v : balloon.triangles[t])
      if (type1[v]) keep[t] = 0;
  // [2] + [3] Normals from unmarked triangles; marked triangles and type-1 vertices go.
  return samples_from(balloon, keep, type1);
}

PointCloud oriented_samples(const Mesh& mesh) {
  check_mesh(mesh, "oriented_samples");
  return samples_from(mesh, std::vector<char>(mesh.triangles.size(), 1),
                      std::vector<char>(mesh.vertices.size(), 0));
}

}  // namespace sonomesh::reconstruct
