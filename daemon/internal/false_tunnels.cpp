// Tunnels no wall explains, filled after the first reconstruction (stages.h).
#include "daemon/internal/stages.h"
#include "daemon/internal/target_image.h"
#include "reconstruct/reconstruct.h"

namespace sonomesh::daemon::internal {

// Tunnels no wall explains are filled: those through the target's own darkness (nothing in them
// reaches the wall's mid level) and the sheets where the balloon's fronts met (nothing in them
// as bright as the tissue), and, on a surface with more handles than a target has, those round
// columns of tissue inside it (nothing in them brighter than the tissue by half the contrast): a
// reader's contour of a cavity takes in its trabeculae and papillary muscles, while a needle's
// specular echo is brighter than tissue and its tunnel stays. No sheet is sought on such a
// surface: its verdict ("implausible genus") sends a low contrast volume to the coarse retry.
void close_false_tunnels(const volume::Volume& smoothed, const Vec3f& seed_mm, int threads,
                         PipelineResult& result, reconstruct::SurfaceResult& surface) {
  const segment::BalloonStats& stats = result.balloon_stats;
  const float contrast = stats.tissue_level - stats.seed_level;
  const bool implausible = surface.topology.genus > kMostHandles;
  reconstruct::TunnelLevels levels{stats.seed_level + 0.5f * contrast, stats.seed_level,
                                   stats.tissue_level};
  // (Fronts meet round a needle; a needle in a probe's sector casts a shadow.)
  if (result.shadow_voxels > 0) levels.widest_sheet_cells = reconstruct::kWidestSheetCells;
  if (implausible) {
    levels.dark_below = stats.tissue_level + 0.5f * contrast;
    levels.sheet_below.reset();
  }
  const bool closed = reconstruct::close_dark_tunnels(surface, seed_mm, smoothed, levels, threads);
  (implausible ? result.tissue_columns_filled : result.dark_tunnels_closed) = closed;
  // A needle whose tip lies in the cavity makes a dent, not a tunnel: a handle it cannot explain
  // is filled as a column's would be (its own echo, brighter than that, keeps the dent).
  if (implausible || surface.topology.genus < 1 || !result.needle_ends_mm ||
      !needle_ends_inside(surface.mesh, *result.needle_ends_mm, smoothed.spacing_mm().minCoeff()))
    return;
  const reconstruct::TunnelLevels columns{stats.tissue_level + 0.5f * contrast, stats.seed_level,
                                          std::nullopt};
  result.needle_dent_filled =
      reconstruct::close_dark_tunnels(surface, seed_mm, smoothed, columns, threads);
}

}  // namespace sonomesh::daemon::internal
