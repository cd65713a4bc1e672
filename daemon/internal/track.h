#pragma once
/// @file
/// @brief Surface tracking (issue 17): a warm volume's surface is the previous result's, fitted to
/// this volume's wall, when nothing says the target changed in a way a fit cannot follow.

#include <string>

#include "daemon/internal/bright_mask.h"
#include "daemon/internal/opinions.h"
#include "daemon/pipeline.h"

namespace sonomesh::daemon::internal {

/// Fits the chain's anchor (track_anchor.h), where the last two volumes' maps predict it, to the
/// wall in `buffers.smoothed` (the pipeline's wall fit, repeated until it settles; the anchor's
/// own fit taken off) and checks the result: hardly any of its area folded over, no larger patch
/// looking into the target's inside than the chain's first result had (a needle withdrawn leaves
/// its tunnel open) nor one that jumped since the last volume (withdrawn half-way), labels that
/// agree with the volume it encloses (else it crossed itself, and is reconstructed from its own
/// samples once, and anchors the chain from there), no bright structure deep inside (a needle
/// inserted or pushed on, bright_inside.h), and an ok verdict. The balloon, its statistics and
/// the topology are carried over; the map is fitted to this volume. Returns why tracking was
/// refused, or empty when `result` holds the judged tracked result (labels included when
/// `config.want_labels`).
std::string track_surface(const volume::Volume& input, const Vec3f& seed_mm,
                          const PipelineConfig& config, const PipelineBuffers& buffers,
                          const PipelineResult& previous, const Judge& judge,
                          PipelineResult& result);

/// The index box (both ends in) that tracking `previous`'s surface reads of the smoothed image:
/// the surface's, grown by how far its fits move it and its tests look beyond it.
IndexBox tracked_region(const volume::Volume& input, const PipelineResult& previous);

/// Sets `result.tracking`'s base on a result the balloon made, for the chain it may start: its
/// open patch (measured when it was not), the deep bright voxels on a line inside it (labels made
/// from its surface when it has none), and its surface as the chain's anchor (track_anchor.h).
void measure_tracking_base(const volume::Volume& input, const PipelineBuffers& buffers,
                           const PipelineConfig& config, PipelineResult& result);

/// Why a chain's `fresh` result (the balloon's, segmenting a tracked volume once more) may not
/// anchor the chain from there on (empty: it may): it failed, is suspect (its reasons said) or
/// has no surface, or its genus is not `tracked_genus`, the chain's. Of two genera one is wrong,
/// and a cold start on the next volume says which (the 128³ echo lv's refresh once went round the
/// near field's clutter at the apex, genus 1; tracked on, three cold starts followed).
std::string unfit_anchor(const PipelineResult& fresh, int tracked_genus);

}  // namespace sonomesh::daemon::internal
