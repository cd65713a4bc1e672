#pragma once
/// @file
/// @brief Correlated Rayleigh speckle and a fixed, portable Gaussian generator.

#include <cstdint>
#include <memory>
#include <vector>

#include "volume/volume.h"

namespace sonomesh::sim::internal {

/// Standard normal pairs from SplitMix64 bits (Box-Muller, fully specified here), so the bytes do
/// not depend on the standard library's distribution implementation.
class GaussianPairs {
 public:
  explicit GaussianPairs(std::uint64_t seed);
  /// Two independent N(0, 1) samples.
  void next(float& a, float& b);

 private:
  std::uint64_t state_;
  std::uint64_t next_bits();
};

/// SplitMix64 finaliser: decorrelates seeds such as (seed, slice index).
std::uint64_t mix64(std::uint64_t x);

/// Speckle multiplier field for a volume: the magnitude of complex Gaussian noise smoothed by a
/// small separable kernel (longer laterally than axially), normalised to mean 1 (Rayleigh, std/mean
/// ~0.52). x fastest. Deterministic in (seed, dims) whatever the thread count. The most recent
/// field is cached, because a streamed series asks for the same one at every frame.
std::shared_ptr<const std::vector<float>> speckle_field(std::uint32_t seed, const volume::Vec3i& dims);

}  // namespace sonomesh::sim::internal
