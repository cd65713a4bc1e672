#include "tests/hil/test_volumes.h"

#include <cstring>

#include "sim/sim.h"

namespace sonomesh::hil {

acquire::RawVolume probe_volume(std::uint64_t sequence, int size, acquire::ProbeVoxelType type) {
  sim::PhantomSpec spec;
  spec.phantom = sequence % 2 ? "torus" : "sphere";
  spec.size_vox = size;
  spec.seed = static_cast<std::uint32_t>(sequence + 1);  // fresh speckle per volume
  spec.time_s = 0.05f * static_cast<float>(sequence);    // breathing motion between volumes
  acquire::RawVolume v = sim::to_raw(sim::make_phantom(spec).image, sequence,
                                     1'000'000'000ull + sequence * 33'000'000ull);
  if (type == acquire::ProbeVoxelType::UInt16) {
    // Widen to 16 bits with a low byte that differs from the high byte, so a byte-order or
    // stride mistake on the way cannot go unnoticed.
    std::vector<std::uint8_t> wide(v.voxels.size() * 2);
    for (std::size_t k = 0; k < v.voxels.size(); ++k) {
      const auto value =
          static_cast<std::uint16_t>((v.voxels[k] << 8) | ((k * 7 + sequence) & 0xFF));
      std::memcpy(&wide[2 * k], &value, 2);  // little endian, as the probe sends it
    }
    v.voxels = std::move(wide);
    v.type = type;
  }
  return v;
}

}  // namespace sonomesh::hil
