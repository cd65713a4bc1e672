#pragma once
/// @file
/// @brief Acoustic shadows undone before the balloon sees the image (docs/stopping.md "The
/// needle's shadow"): the probe's apex from its sector, the thin bright reflectors that darken
/// what lies beyond them along the beam, and a gain that lifts their shadows to the level beside.

#include <array>
#include <cstdint>
#include <optional>
#include <vector>

#include "daemon/internal/bright_mask.h"
#include "volume/volume.h"

namespace sonomesh::daemon::internal {

/// The probe's apex in mm (the grid frame, Volume::index_to_mm) from the side walls of its
/// no-data region (`no_data` as no_data_mask; 1 outside the sector): the point every side wall's
/// plane passes through. nullopt when there is no region or its walls do not meet in one point
/// (the median wall's normal more than 0.15 in sine from square to its ray: not a sector).
std::optional<volume::Vec3f> sector_apex_mm(const volume::Volume& input,
                                            const std::vector<std::uint8_t>& no_data);

/// The q-quantile of v (0 when empty).
float quantile(std::vector<float> v, float q);

/// What compensate_shadows found: the voxels it lifted and by how much (1 = none).
struct ShadowGain {
  int casters = 0;                      // voxels of the bright clusters that cast a shadow
  std::size_t voxels = 0;               // voxels lifted
  float shadow_factor = 1.0f;           // the shadow's level over the level beside it
  std::optional<IndexBox> casters_box;  // the casters' bounding box, when there are casters
  float bright_level = 0.0f;            // the level a caster's 7-voxel cross lies over
  bool searched_near = false;           // the casters came from the search near `near` (see below)
  // The casters' two ends along their principal line, mm (a needle's: where it enters the
  // volume or the sector, and its tip), when there are casters.
  std::optional<std::array<volume::Vec3f, 2>> ends_mm;
};

/// Lifts the acoustic shadows in `image` (Float32; the working image, the no-data region already
/// filled) by 1 / the shadow's factor. Casters are the far side, along the beam, of bright
/// clusters: face-connected voxels that with their 7-voxel cross average over 1.8 times the
/// sector's median and its 90th percentile (a needle; speckle and tissue walls are not that
/// bright), 20 or more and 12 voxels long or more (a line, not a speckle grain). A caster's
/// beam, 3-20 voxels beyond it, reads under 0.6 of the same mean 6 voxels across the beam on
/// both sides; a cluster casts when 20 of its far side and a third of those tested do; the
/// factor is their median. The shadow is every voxel whose beam from the apex passed a caster
/// more than a voxel before it (less on its edge). `threads` as segment::BalloonOptions::threads;
/// the result is the same for any count. With `near` (the last volume's casters_box) only the
/// clusters with a voxel in that box grown by 6 voxels are judged (each grown whole), and all of
/// them where that finds no caster. With `within` (an index box, both ends in) only its voxels
/// are lifted and counted.
ShadowGain compensate_shadows(volume::Volume& image, const std::vector<std::uint8_t>& no_data,
                              const volume::Vec3f& apex_mm, int threads = 0,
                              const IndexBox* near = nullptr, const IndexBox* within = nullptr);

}  // namespace sonomesh::daemon::internal
