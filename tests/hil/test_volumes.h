#pragma once
/// @file
/// @brief Volumes the emulated probes send in the hil tests.

#include <cstdint>

#include "acquire/raw_volume.h"

namespace sonomesh::hil {

/// A simulated probe volume: a speckled phantom from sim::make_phantom, cubic of edge `size`,
/// UInt8 or (widened, using the full 16-bit range) UInt16. Different sequences give different
/// bytes, so a swapped or stale volume cannot pass a bit-exact comparison.
acquire::RawVolume probe_volume(std::uint64_t sequence, int size,
                                acquire::ProbeVoxelType type = acquire::ProbeVoxelType::UInt8);

}  // namespace sonomesh::hil
