#pragma once
/// @file
/// @brief Topology of a voxel set, for checking phantom truth: Euler characteristic of the union
/// of closed voxel cubes, component and cavity counts.

#include <array>
#include <cstdint>
#include <queue>
#include <vector>

#include "volume/volume.h"

namespace sonomesh::sim::testing {

struct SolidTopology {
  long euler = 0;      // chi = V - E + F - C of the closed cubical complex
  int components = 0;  // 26-connected (closed cubes sharing a vertex touch)
  int cavities = 0;    // bounded 6-connected background components
  /// First Betti number (tunnels): b1 = b0 + b2 - chi. For one component without cavities this is
  /// the genus of the boundary surface.
  long tunnels() const { return components + cavities - euler; }
};

inline SolidTopology solid_topology(const volume::Volume& labels) {
  const auto& lab = labels.u8();
  const int nx = labels.dims().x(), ny = labels.dims().y(), nz = labels.dims().z();
  auto on = [&](int i, int j, int k) {
    if (i < 0 || j < 0 || k < 0 || i >= nx || j >= ny || k >= nz) return false;
    return lab[labels.linear_index(i, j, k)] != 0;
  };
  // Cells of the complex on the vertex lattice (nx+1)(ny+1)(nz+1); a cell is in the complex if any
  // voxel containing it is on. Cell type by which axes it spans.
  const int vx = nx + 1, vy = ny + 1, vz = nz + 1;
  auto vid = [&](int i, int j, int k) { return (static_cast<std::size_t>(k) * vy + j) * vx + i; };
  const std::size_t nv = static_cast<std::size_t>(vx) * vy * vz;
  // mask bits: 0 vertex, 1..3 edges along x/y/z, 4..6 faces normal to x/y/z.
  std::vector<std::uint8_t> mask(nv, 0);
  SolidTopology topo;
  long cubes = 0;
  for (int k = 0; k < nz; ++k)
    for (int j = 0; j < ny; ++j)
      for (int i = 0; i < nx; ++i) {
        if (!on(i, j, k)) continue;
        ++cubes;
        for (int c = 0; c < 8; ++c) {
          const int di = c & 1, dj = (c >> 1) & 1, dk = (c >> 2) & 1;
          std::uint8_t bits = 1;               // vertex
          if (di == 0) bits |= 2;              // x-edge starting here
          if (dj == 0) bits |= 4;              // y-edge
          if (dk == 0) bits |= 8;              // z-edge
          if (dj == 0 && dk == 0) bits |= 16;  // face spanning y,z (normal x)
          if (di == 0 && dk == 0) bits |= 32;  // face normal y
          if (di == 0 && dj == 0) bits |= 64;  // face normal z
          mask[vid(i + di, j + dj, k + dk)] |= bits;
        }
      }
  long v = 0, e = 0, f = 0;
  for (auto m : mask) {
    v += m & 1;
    e += ((m >> 1) & 1) + ((m >> 2) & 1) + ((m >> 3) & 1);
    f += ((m >> 4) & 1) + ((m >> 5) & 1) + ((m >> 6) & 1);
  }
  topo.euler = v - e + f - cubes;

  // Foreground components, 26-connectivity.
  std::vector<std::uint8_t> seen(lab.size(), 0);
  std::queue<std::array<int, 3>> q;
  for (int k = 0; k < nz; ++k)
    for (int j = 0; j < ny; ++j)
      for (int i = 0; i < nx; ++i) {
        if (!on(i, j, k) || seen[labels.linear_index(i, j, k)]) continue;
        ++topo.components;
        seen[labels.linear_index(i, j, k)] = 1;
        q.push({i, j, k});
        while (!q.empty()) {
          const auto [a, b, c] = q.front();
          q.pop();
          for (int dk = -1; dk <= 1; ++dk)
            for (int dj = -1; dj <= 1; ++dj)
              for (int di = -1; di <= 1; ++di) {
                const int x = a + di, y = b + dj, z = c + dk;
                if (on(x, y, z) && !seen[labels.linear_index(x, y, z)]) {
                  seen[labels.linear_index(x, y, z)] = 1;
                  q.push({x, y, z});
                }
              }
        }
      }

  // Background components, 6-connectivity, on a grid padded by one voxel so the outside is one.
  const int px = nx + 2, py = ny + 2, pz = nz + 2;
  auto pid = [&](int i, int j, int k) { return (static_cast<std::size_t>(k) * py + j) * px + i; };
  std::vector<std::uint8_t> bg_seen(static_cast<std::size_t>(px) * py * pz, 0);
  int background = 0;
  for (int k = 0; k < pz; ++k)
    for (int j = 0; j < py; ++j)
      for (int i = 0; i < px; ++i) {
        if (on(i - 1, j - 1, k - 1) || bg_seen[pid(i, j, k)]) continue;
        ++background;
        bg_seen[pid(i, j, k)] = 1;
        q.push({i, j, k});
        while (!q.empty()) {
          const auto [a, b, c] = q.front();
          q.pop();
          const int nb[6][3] = {{1, 0, 0},  {-1, 0, 0}, {0, 1, 0},
                                {0, -1, 0}, {0, 0, 1},  {0, 0, -1}};
          for (const auto& d : nb) {
            const int x = a + d[0], y = b + d[1], z = c + d[2];
            if (x < 0 || y < 0 || z < 0 || x >= px || y >= py || z >= pz) continue;
            if (on(x - 1, y - 1, z - 1) || bg_seen[pid(x, y, z)]) continue;
            bg_seen[pid(x, y, z)] = 1;
            q.push({x, y, z});
          }
        }
      }
  topo.cavities = background - 1;
  return topo;
}

}  // namespace sonomesh::sim::testing
