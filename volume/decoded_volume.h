#pragma once
/// @file
/// @brief A Volume read from a file, handed through acquire (replay) as RawVolume::decoded, so
/// that Volume::from_raw takes it as it is instead of packing its voxels into probe bytes and
/// unpacking them again.

#include <cstdint>
#include <vector>

#include "acquire/raw_volume.h"
#include "volume/volume.h"

namespace sonomesh::volume {

class DecodedVolume final : public acquire::DecodedPayload {
 public:
  explicit DecodedVolume(Volume volume) : volume_(std::move(volume)) {}
  const Volume& volume() const { return volume_; }
  /// uint8 and uint16 voxels as little-endian bytes; empty for other types.
  std::vector<std::uint8_t> probe_voxels() const override;

 private:
  Volume volume_;
};

}  // namespace sonomesh::volume
