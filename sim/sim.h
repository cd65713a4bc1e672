#pragma once
/// @file
/// @brief Synthetic ultrasound phantoms with ground truth: what a probe would deliver.

#include <cstdint>
#include <string>
#include <vector>

#include "acquire/raw_volume.h"
#include "volume/volume.h"

namespace sonomesh::sim {

using volume::Vec3f;
using volume::Vec3i;

/// Parameters of a synthetic volume. Defaults give a typical speckled hypoechoic target.
struct PhantomSpec {
  std::string phantom = "sphere";  // sphere | ellipsoid | torus | cyst-needle | double-torus
  int size_vox = 64;               // edge of the cubic volume, voxels
  Vec3f spacing_mm{0.5f, 0.5f, 0.5f};
  float contrast = 0.7f;           // 1 - target_mean / tissue_mean: 0 invisible, 1 black target
  float speckle = 0.5f;            // speckle strength, 0 = none
  float attenuation_db_per_cm = 0.5f;  // attenuation with depth (z) in dB/cm (round trip)
  std::uint32_t seed = 1;          // random seed: same seed, same bytes
  float time_s = 0.0f;             // breathing phase for streamed phantoms: moves/deforms a little
  Vec3f axis{0.0f, 0.0f, 1.0f};    // orientation of the torus / ellipsoid / cyst major axis
  // Direction the biopsy needle points (cyst-needle only), from entry towards its tip. Default:
  // 30 degrees below lateral, as a needle guided into the beam; a needle along the beam (z) would
  // cast its shadow into itself and show nothing a probe could see.
  Vec3f needle_axis{0.866f, 0.0f, 0.5f};
};

/// A phantom: the image a probe would deliver and its ground truth.
struct Phantom {
  volume::Volume image;  // UInt8, the ultrasound-like image
  volume::Volume truth;  // UInt8 labels on the same grid, inside the target = 1
  std::string name;
  int genus = 0;         // topology of the target surface
  Vec3i seed_index = Vec3i::Zero();  // a voxel well inside the target
  Vec3f seed_mm = Vec3f::Zero();     // the same point in mm
};

/// Names accepted in PhantomSpec::phantom.
const std::vector<std::string>& phantom_names();

/// Builds a phantom. Deterministic in the spec.
/// @throws std::invalid_argument naming the field for an unknown phantom or a size below 16.
Phantom make_phantom(const PhantomSpec& spec);

/// The phantom's image as a probe record (sequence and timestamp as given).
acquire::RawVolume to_raw(const volume::Volume& image, std::uint64_t sequence,
                          std::uint64_t timestamp_ns);

}  // namespace sonomesh::sim
