#pragma once
/// @file
/// @brief What `sonomeshd run`'s worker tells the live page and systemd (issue 18). Plain
/// callbacks so that the worker needs no knowledge of HTTP or sd_notify; both may be empty.

#include <cstdint>
#include <functional>

#include "segment/mesh.h"
#include "volume/volume.h"

namespace sonomesh::daemon {

struct LiveHooks {
  /// Every turn of the processing loop (idle or not): feeds systemd's watchdog.
  std::function<void()> worker_turn;
  /// A volume's surface is ready: the volume, the mesh and the seed used, in the grid frame.
  std::function<void(const volume::Volume& input, const segment::Mesh& mesh_mm,
                     const volume::Vec3f& seed_mm, std::uint64_t sequence)>
      result;
};

}  // namespace sonomesh::daemon
