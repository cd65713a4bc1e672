#pragma once
/// @file
/// @brief The surface a tracking chain follows (track.h): the chain's first result's, carried to
/// each volume by an affine map. Each volume's fit starts from the anchor where the maps predict
/// it, not from the last fitted surface, so the speckle grains one fit follows are not carried
/// into the next: fitted from the last surface, an echo chain drifted off the wall
/// (docs/tuning.md, "Surface tracking").

#include <memory>
#include <vector>

#include "daemon/pipeline.h"

namespace sonomesh::daemon::internal {

/// A chain's first surface, its vertices' centroid, and how far along its normals the tracking
/// fit (follow_wall) moves each vertex on the surface's own volume: the fit's bias on the
/// smoothed image (a wall facing the probe comes out inside, where the pipeline's last fit, on
/// the unsmoothed image, put it right), which each tracked volume's fit takes off again.
struct TrackingAnchor {
  segment::Mesh surface;
  Vec3f centre_mm = Vec3f::Zero();
  std::vector<float> own_fit_mm;
};

/// The mean of `surface`'s vertices.
Vec3f vertex_centroid_mm(const segment::Mesh& surface);

/// The tracking fit: `start` fitted to the wall in `smoothed` (the pipeline's wall fit), repeated
/// while it still moves the surface.
segment::Mesh follow_wall(const volume::Volume& smoothed, const segment::Mesh& start,
                          const segment::BalloonStats& levels, const PipelineConfig& config);

/// `result`'s surface as a chain's anchor, its own fit measured on `smoothed` (its volume's);
/// none where `result` has no seed and tissue levels for the fit.
std::shared_ptr<const TrackingAnchor> make_anchor(const volume::Volume& smoothed,
                                                  const PipelineResult& result,
                                                  const PipelineConfig& config);

/// The tracking's anchor where its map puts it (same vertices and triangles).
segment::Mesh mapped_anchor(const PipelineResult::Tracking& tracking);

/// The anchor where the next volume's map is expected: the map moved on from this volume's as
/// it moved from the last one's. A breath moves the wall smoothly, so the next volume's fits
/// start nearer their end, and settle in fewer rounds.
segment::Mesh predicted_anchor(const PipelineResult::Tracking& tracking);

/// `fitted` (`start`, the mapped anchor, fitted to this volume's wall) without the anchor's own
/// fit, each vertex moved back along `start`'s normal.
void take_off_own_fit(const TrackingAnchor& anchor, const segment::Mesh& start,
                      segment::Mesh& fitted);

/// Sets `tracking`'s map to the affine one that takes its anchor to `fitted` (the anchor's
/// vertices, moved), in the least squares of the distances along `fitted`'s normals; the map it
/// had becomes the last one.
void fit_anchor_map(const segment::Mesh& fitted, float vox_mm, PipelineResult::Tracking& tracking);

}  // namespace sonomesh::daemon::internal
