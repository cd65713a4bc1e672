#include "tests/hil/test_volumes.h"

#include <cstring>

namespace sonomesh::hil {

acquire::RawVolume probe_volume(std::uint64_t sequence, int size, acquire::ProbeVoxelType type) {
  acquire::RawVolume v;
  v.sequence = sequence;
  v.timestamp_ns = 1'000'000'000ull + sequence * 33'000'000ull;
  v.dims = {size, size, size};
  v.type = type;
  v.spacing_mm = {0.5f, 0.5f, 0.6f};
  const std::size_t n = static_cast<std::size_t>(size) * size * size;
  v.voxels.resize(n * static_cast<std::size_t>(acquire::bytes_per_voxel(type)));
  // Deterministic speckle-like bytes (xorshift), different per sequence.
  std::uint64_t s = 0x9E3779B97F4A7C15ull ^ (sequence * 0xBF58476D1CE4E5B9ull);
  for (std::size_t i = 0; i < v.voxels.size(); ++i) {
    s ^= s << 13;
    s ^= s >> 7;
    s ^= s << 17;
    v.voxels[i] = static_cast<std::uint8_t>(s >> 24);
  }
  return v;
}

}  // namespace sonomesh::hil
