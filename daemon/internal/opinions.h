#pragma once
/// @file
/// @brief The second opinion and the coarse retry (docs/stopping.md departures 9 and 12): the
/// pipeline's stages (stages.h) run again with the other stop rule or a coarser pre-filter, and
/// the better result kept.

#include <functional>
#include <stop_token>
#include <string>

#include "daemon/pipeline.h"

namespace sonomesh::daemon::internal {

/// Judges a result: sets ok, error and the quality verdict.
using Judge = std::function<void(PipelineResult&, std::string)>;

/// One scale's segmentation: the first stop rule (the one the warm start's result came from),
/// and where its cold result is suspect or missing, the other rule's on the same smoothed volume
/// (the second opinion, docs/stopping.md departure 9), the better kept. A warm result had an ok
/// one before it with the same rule: when it is suspect, this volume is the odd one, and the next
/// starts cold and may get the second opinion, so a live stream does not stall on one. With
/// `known_target` (the last result, when this cold start follows tracked volumes of this
/// target) an ok result is not asked again for looking down a tube, and its rule runs first, as
/// a warm start's does. Sets `judged` when `result` has its verdict. Returns the error, empty if
/// there is a surface.
std::string segment_opinions(const volume::Volume& input, const Vec3f& seed_mm,
                             const PipelineConfig& config, PipelineBuffers& buffers,
                             const WarmStart* warm, const std::stop_token& stop, const Judge& judge,
                             PipelineResult& result, bool& judged,
                             const PipelineResult* known_target = nullptr);

/// The verdict's reasons for a balloon that stopped on the texture around the seed, or wrapped
/// round it (more handles than a seeded target has: columns of speckle inside the cavity).
bool stalled_on_texture(const PipelineResult& r);

/// Whether the coarse retry is tried on `r` (after both stop rules): it stalled on the texture,
/// or the verdict calls its contrast low.
bool wants_coarse_retry(const PipelineResult& r);

/// The coarse retry (docs/stopping.md departure 12): at low contrast both stop rules stop on the
/// speckle the grain-sized pre-filter leaves; a coarser one averages it out at the price of the
/// wall's sharpness. Its result replaces a stalled `result` unless it stalled as well and is no
/// better; one suspect only for its low contrast where it is the better one, encloses more and
/// keeps the handles of a needle seen across it. It is then fitted to the wall on a finer image
/// (the fine fit).
void coarse_retry(const volume::Volume& input, const Vec3f& seed_mm, const PipelineConfig& config,
                  PipelineBuffers& buffers, const std::stop_token& stop, const Judge& judge,
                  PipelineResult& result, std::string& error);

}  // namespace sonomesh::daemon::internal
