#pragma once
/// @file
/// @brief Per-vertex lists over a triangle mesh's corners (CSR), for the passes that keep the
/// connectivity fixed (reinflate, fit_to_wall) and so need no halfedges.

#include <cstdint>
#include <stdexcept>
#include <string>
#include <vector>

#include "segment/segment.h"

namespace sonomesh::segment::internal {

/// Vertex v's list is begin[v] .. begin[v + 1] of `list`: one entry `pick(f, k)` for each corner k
/// of each triangle f at v, in triangle order.
struct CornerTable {
  std::vector<std::uint32_t> begin, list;

  /// @throws std::invalid_argument naming `who` when a triangle indexes no vertex.
  template <typename Pick>
  CornerTable(const Mesh& surface, const char* who, Pick pick) {
    const std::size_t nv = surface.vertices.size(), nf = surface.triangles.size();
    begin.assign(nv + 1, 0);
    for (const auto& t : surface.triangles)
      for (const std::uint32_t v : t) {
        if (v >= nv)
          throw std::invalid_argument(std::string(who) + ": triangle index out of range");
        ++begin[v + 1];
      }
    for (std::size_t v = 0; v < nv; ++v) begin[v + 1] += begin[v];
    list.resize(begin[nv]);
    std::vector<std::uint32_t> fill(begin.begin(), begin.end() - 1);
    for (std::uint32_t f = 0; f < nf; ++f)
      for (int k = 0; k < 3; ++k) list[fill[surface.triangles[f][k]]++] = pick(f, k);
  }
  std::uint32_t degree(std::uint32_t v) const { return begin[v + 1] - begin[v]; }
};

}  // namespace sonomesh::segment::internal
