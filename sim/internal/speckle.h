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

using volume::Vec3f;

/// The simple mode's grain: Gaussian sigma 1.0 voxel laterally (x, y), 0.6 voxel axially (z).
inline const Vec3f kDefaultSpeckleSigmaVox{1.0f, 1.0f, 0.6f};

/// Speckle multiplier field for a volume: the magnitude of complex Gaussian noise smoothed by a
/// separable Gaussian of sigma_vox per axis (the grain; longer laterally than axially), normalised
/// to mean 1 (Rayleigh, std/mean ~0.52). x fastest. Deterministic in (seed, dims, sigma_vox)
/// whatever the thread count. The two most recent fields are cached, because a streamed series
/// asks for the same one at every frame.
std::shared_ptr<const std::vector<float>> speckle_field(
    std::uint32_t seed, const volume::Vec3i& dims, const Vec3f& sigma_vox = kDefaultSpeckleSigmaVox);

}  // namespace sonomesh::sim::internal
