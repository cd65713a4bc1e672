// Opening the balloon (method.md §4; paper §4, steps [1]-[3]).

#include <stdexcept>
#include <string>

#include "reconstruct/reconstruct.h"

namespace sonomesh::reconstruct {

PointCloud open_balloon(const Mesh& balloon, const std::vector<StopReason>& stop) {
  if (stop.size() != balloon.vertices.size())
    throw std::invalid_argument("open_balloon: stop.size() (" + std::to_string(stop.size()) +
                                ") != balloon.vertices.size() (" +
                                std::to_string(balloon.vertices.size()) + ")");
  for (const auto& t : balloon.triangles)
    for (auto v : t)
      if (v >= balloon.vertices.size())
        throw std::invalid_argument("open_balloon: triangle index " + std::to_string(v) +
                                    " out of range (" + std::to_string(balloon.vertices.size()) +
                                    " vertices)");
  // [1] Type-1 vertices and the triangles that touch them.
  std::vector<char> type1(balloon.vertices.size(), 0);
  for (std::size_t v = 0; v < stop.size(); ++v) type1[v] = stop[v] == StopReason::SelfIntersection;
  std::vector<char> keep(balloon.triangles.size(), 1);
  for (std::size_t t = 0; t < balloon.triangles.size(); ++t)
    for (auto v : balloon.triangles[t])
      if (type1[v]) keep[t] = 0;
  // [2] + [3] Normals from unmarked triangles; marked triangles and type-1 vertices go.
  return mesh::oriented_samples(balloon, keep, type1);
}

}  // namespace sonomesh::reconstruct
