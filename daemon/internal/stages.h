#pragma once
/// @file
/// @brief The per-volume pipeline's stages (daemon/internal/pipeline.cpp), for the second opinion
/// and the coarse retry (opinions.h), which run them again, and surface tracking (track.h).

#include <cstdint>
#include <optional>
#include <stop_token>
#include <string>
#include <vector>

#include "daemon/internal/bright_mask.h"
#include "daemon/internal/clock.h"
#include "daemon/pipeline.h"

namespace sonomesh::daemon::internal {

/// Where smooth_stage looks for a needle's shadow (`config.shadow_gain`): in the whole volume,
/// first near the casters the buffers' last search found (a tracked volume), or nowhere.
enum class ShadowSearch { Whole, NearLast, None };

/// §0: what the balloon sees and its pre-filter (docs/stopping.md), into `buffers.smoothed`.
/// Returns the probe's no-data mask for a dark target (in `buffers`), else an empty one. With
/// `region` (a tracked volume: the index box, both ends in, that its readers look in) only that
/// box of `buffers.smoothed` is made; the rest holds what an earlier volume left.
const std::vector<std::uint8_t>& smooth_stage(const volume::Volume& input, const Vec3f& seed_mm,
                                              const PipelineConfig& config,
                                              PipelineBuffers& buffers, PipelineResult& result,
                                              ShadowSearch search = ShadowSearch::Whole,
                                              const IndexBox* region = nullptr);

/// `config` for the volume smooth_stage gave `result`: its wall fit told the probe's apex where
/// that found one for a dark target (segment::WallFitOptions::probe_apex_mm).
PipelineConfig with_probe_apex(const PipelineConfig& config, const PipelineBuffers& buffers,
                               const PipelineResult& result);

/// The same volume smoothed again at `sigma_mm` (the coarse retry, the fine fit), after
/// smooth_stage gave `first`: the image it left in `buffers` (polarity, no-data fill, lifted
/// shadow) is smoothed as it is, not made again; `result` takes first's grain, polarity and
/// shadow.
void smooth_again(const volume::Volume& input, const PipelineResult& first, float sigma_mm,
                  PipelineBuffers& buffers, PipelineResult& result);

/// The image smooth_stage smoothed for `first` (polarity, no-data fill, lifted shadow), before
/// its pre-filter, as Float32: buffers.working, which takes a copy of the input where the input
/// was smoothed as it is.
const volume::Volume& unsmoothed_image(const volume::Volume& input, const PipelineResult& first,
                                       PipelineBuffers& buffers);

/// The reconstruction's options for `input`: the configured ones, on cells of its finest spacing
/// when `config.cell_from_voxel`.
reconstruct::PoissonOptions poisson_options(const PipelineConfig& config,
                                            const volume::Volume& input);

/// How much coarser than the voxel a reconstruction of `surface` (closed) may be: its thickness
/// 3V/A (a ball's radius, 1.5 times a tube's) over 12 voxels, between 1 and 1.5. 12 keeps a 96³
/// phantom's double torus (about 10 voxels) on voxel cells: on 1.5-voxel cells it lost a tube.
float thick_cell_scale(const segment::Mesh& surface, float vox_mm);

/// Tunnels no wall explains filled on the first reconstruction (reconstruct::close_dark_tunnels
/// at the balloon's levels): through the target's own darkness, sheets where the balloon's fronts
/// met, and on a surface of more handles than a target has, round columns of tissue; `result`
/// says which (dark_tunnels_closed, tissue_columns_filled).
void close_false_tunnels(const volume::Volume& smoothed, const Vec3f& seed_mm, int threads,
                         PipelineResult& result, reconstruct::SurfaceResult& surface);

/// `surface` (closed, of `genus`) made again from its own oriented samples by Kazhdan's
/// reconstruction, on cells 1.25 times the configured ones (`coarser_when_thick` with
/// `cell_from_voxel`: or thick_cell_scale's, if coarser), then on the configured ones where that
/// lost the genus: unset where both lost the seed, the genus or the one closed manifold component.
/// (A tracked chain remakes each surface from the last: on the coarser cells a 96³ echo chain
/// drifted 0.004 of Dice further off the wall over seven volumes.)
std::optional<reconstruct::SurfaceResult> resurfaced(const volume::Volume& input,
                                                     const segment::Mesh& surface, int genus,
                                                     const Vec3f& seed_mm,
                                                     const PipelineConfig& config,
                                                     bool coarser_when_thick = false);

/// `surface`, enclosing `has_ml`, moved along its normals (mesh::vertex_normals) by the one
/// distance that makes it enclose `volume_ml`; the vertices `held` (per vertex, 1: held; empty:
/// none) stay where they are.
void keep_volume(segment::Mesh& surface, double has_ml, double volume_ml,
                 const std::vector<char>& held = {});

/// Beyond the paper, after the wall fit (PipelineConfig::fit_unsmoothed): `result`'s surface
/// fitted once more, on the unsmoothed image and over more rings, then moved along its normals
/// back to the volume it enclosed. The pre-filter blurs a wall along the normal, which the rings
/// alone do not, so the unsmoothed image gives the wall's shape; but its speckle lifts the level
/// ahead of a vertex and moves the crossing half way to it outward, so the smoothed image gives
/// where the wall lies on average (docs/stopping.md item 13). Vertices whose wall faces the
/// probe (buffers' apex) keep their unsmoothed crossing; the others move to keep the volume.
/// Measures `result.fitted_wall_support` first.
void fit_unsmoothed(const volume::Volume& input, PipelineBuffers& buffers,
                    const PipelineConfig& config, PipelineResult& result);

/// Beyond the paper, after the wall fit (PipelineConfig::resurface): the fitted surface
/// `resurfaced`, moved along its normals to the fitted surface's volume, kept where that holds
/// (PipelineResult::resurfaced); then, where the surface has no tunnel, a bright structure it
/// passed over in `smoothed` is opened (docs/stopping.md item 14).
void resurface_stage(const volume::Volume& input, const volume::Volume& smoothed,
                     const Vec3f& seed_mm, const PipelineConfig& config, PipelineResult& result);

/// segment_stages in its two steps, for the second opinion (opinions.h), which looks at a
/// balloon before its surface is made: the balloon (warm, or cold) into `result`, returning the
/// error, empty if there is one...
std::string balloon_step(const Vec3f& seed_mm, const PipelineConfig& config,
                         PipelineBuffers& buffers, const WarmStart* warm,
                         const std::stop_token& stop, PipelineResult& result);
/// ...then the rest from `result`'s balloon, returning the error, empty if there is a surface.
std::string surface_steps(const volume::Volume& input, const Vec3f& seed_mm,
                          const PipelineConfig& config, PipelineBuffers& buffers,
                          const WarmStart* warm, const std::stop_token& stop,
                          PipelineResult& result);

/// §1-5 and the second pass, after the smoothing: the balloon (warm, or cold), the surface, the
/// reinflation and the wall fit, the surface made again. Returns the error, empty if there is a
/// surface.
std::string segment_stages(const volume::Volume& input, const Vec3f& seed_mm,
                           const PipelineConfig& config, PipelineBuffers& buffers,
                           const WarmStart* warm, const std::stop_token& stop,
                           PipelineResult& result);

}  // namespace sonomesh::daemon::internal
