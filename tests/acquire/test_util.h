#pragma once
// Helpers shared by the acquire tests.
#include <cstdint>
#include <random>
#include <vector>

#include "acquire/protocol.h"

namespace sonomesh::acquire::test {

inline RawVolume make_volume(std::uint64_t sequence, std::array<int, 3> dims = {32, 32, 32},
                             ProbeVoxelType type = ProbeVoxelType::UInt8) {
  RawVolume v;
  v.sequence = sequence;
  v.timestamp_ns = 1'000'000'000ull + sequence * 40'000'000ull;
  v.dims = dims;
  v.type = type;
  v.spacing_mm = {0.5f, 0.6f, 0.7f};
  v.origin_mm = {-1.0f, 2.0f, 3.5f};
  v.voxels.resize(static_cast<std::size_t>(dims[0]) * dims[1] * dims[2] * bytes_per_voxel(type));
  std::mt19937 rng(static_cast<std::uint32_t>(sequence * 7919 + 1));
  for (auto& b : v.voxels) b = static_cast<std::uint8_t>(rng());
  return v;
}

inline std::vector<std::uint8_t> record(const RawVolume& v) {
  auto bytes = encode_volume_record(v);
  return bytes ? *bytes : std::vector<std::uint8_t>{};
}

inline void append(std::vector<std::uint8_t>& out, const std::vector<std::uint8_t>& bytes) {
  out.insert(out.end(), bytes.begin(), bytes.end());
}

}  // namespace sonomesh::acquire::test
