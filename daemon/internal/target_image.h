#pragma once
/// @file
/// @brief The image the balloon sees (docs/stopping.md): the target's polarity resolved, a bright
/// target inverted into a dark one, and a probe's no-data region (zeros outside the sector) kept
/// from acting as a darker target; plus the quality verdict on the result.

#include <array>
#include <cstdint>
#include <string>
#include <vector>

#include "daemon/pipeline.h"

namespace sonomesh::daemon::internal {

/// Voxels outside a probe's sector: value exactly 0 and connected through such voxels to the
/// volume's border. Empty when there is no such region or it covers under 2 % of the volume (a
/// simulator volume, a zero speckle voxel). Index as Volume::linear_index.
std::vector<std::uint8_t> no_data_mask(const volume::Volume& input);

/// Dark or bright from the seed region against its surroundings: along 64 rays from the seed, the
/// first sustained departure of the local mean (a cube of about one speckle grain) from the seed's
/// level, upwards (a brighter wall: a dark target) or downwards (a bright target). The majority
/// decides; a tie or no departure at all is dark (the tool's default).
TargetPolarity decide_polarity(const volume::Volume& input, const Vec3f& seed_mm, float grain_mm);

using NoDataRegion = PipelineBuffers::NoDataRegion;

/// Makes `region` the no-data region of `input` (the mask no_data_mask gives, and the plan of
/// working_image's fill over it). A region kept from the last volume stays when it still holds:
/// every voxel of it is zero and no other zero lies beside it or on the border. Returns whether
/// it was kept.
bool update_no_data(const volume::Volume& input, NoDataRegion& region);

/// Whether working_image rewrites the input (a bright target, or a dark one with a no-data
/// region) rather than leaving it as it is.
bool needs_working_image(TargetPolarity target, const NoDataRegion& no_data);

/// `input` as Float32 in `out` (its buffer kept when it has the size; origin and direction set).
void copy_as_float32(const volume::Volume& input, volume::Volume& out);

/// What the balloon segments as a dark target, as Float32 in `out` (its buffer kept when it has
/// the size): the input inverted (max − I) for a bright target; for a dark one with a no-data
/// region, each voxel of the region within 16 voxels of the data given the value of the data
/// nearest to it (zeros are darker than any dark target: left as they are, the balloon runs out
/// into them). Returns false when the input can be used as it is.
bool working_image(const volume::Volume& input, TargetPolarity target, const NoDataRegion& no_data,
                   volume::Volume& out);

/// Share of the surface's vertices (up to 4000 of them, evenly spread) with a wall beyond them in
/// the smoothed image the balloon saw: the mean 2-5 voxels outside above the mean 1-3 voxels
/// inside by half the contrast between `target_level` and `tissue_level`. −1 when it cannot be
/// measured (no image, no surface, no contrast).
float wall_support(const volume::Volume& smoothed, const segment::Mesh& surface, float target_level,
                   float tissue_level);

/// Share of the surface's area in its largest connected patch of triangles that look into the
/// target's inside: the smoothed image's mean 1-5 voxels beyond a triangle's centre lies within
/// 0.15 of the contrast above `target_level` (`tissue_level` sets the contrast). With
/// `local_levels`, where the image 1-3 voxels behind the triangle is under 0.8 of `target_level`
/// (a shadow), above that level instead, by 0.15 of the contrast scaled by it over
/// `target_level` (a wall in a needle's shadow is darker on both sides, not open). −1 when it
/// cannot be measured. `threads` as segment::BalloonOptions::threads.
float open_patch(const volume::Volume& smoothed, const segment::Mesh& surface, float target_level,
                 float tissue_level, int threads = 0, bool local_levels = false);

/// More handles than a target a clinician seeds has (a cyst none, a needle through it one, two
/// needles two): the balloon wrapped round columns of tissue or clutter inside a cavity.
constexpr int kMostHandles = 2;

/// Whether the needle's line (its two ends, mm) runs into the inside of the closed `surface` 4-8
/// voxels past either end: the needle ends inside the target, where the surface can only dent
/// round it, so no handle of the surface is the needle's tunnel.
bool needle_ends_inside(const segment::Mesh& surface, const std::array<Vec3f, 2>& ends,
                        float vox_mm);

/// Fills result.quality_ok / quality_reasons (DESIGN.md "the quality verdict") from the balloon and
/// the final surface: stalled near the seed, implausibly small, touching the volume's edge or the
/// sector's (no data beyond), the iteration limit, the leak bound, and a wall_support under 3/4
/// in `smoothed` (skipped when `smoothed` is empty).
void quality_verdict(const volume::Volume& input, const volume::Volume& smoothed,
                     const std::vector<std::uint8_t>& no_data, const Vec3f& seed_mm,
                     PipelineResult& result);

/// The verdict's reasons its balloon alone gives (the leak bound, a sealed leak, stalled near the
/// seed, the iteration limit), appended to `why`: a result with one of them is suspect whatever
/// its surface.
void balloon_reasons(const volume::Volume& input, const Vec3f& seed_mm,
                     const PipelineResult& result, std::vector<std::string>& why);

}  // namespace sonomesh::daemon::internal
