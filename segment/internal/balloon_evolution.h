#pragma once
/// @file
/// @brief The balloon's first pass (method.md §1-3) as a class: one object per inflation, its
/// phases (Euler step with the stop tests, normals, A_t marking, stall test, remeshing) methods.

#include <cstdint>
#include <limits>
#include <optional>
#include <stop_token>
#include <string>
#include <vector>

#include "mesh/parallel.h"
#include "segment/internal/balloon_mesh.h"
#include "segment/internal/flat_arrays.h"
#include "segment/internal/front_grid.h"
#include "segment/internal/image_sampler.h"
#include "segment/internal/step.h"
#include "segment/internal/stop_rules.h"

namespace sonomesh::segment::internal {

/// The remeshing range at the target edge length L: collapse < 4/5 L, split > 4/3 L.
RemeshLimits remesh_limits(const BalloonOptions& options, float vox_mm);

/// The cold start's S^0: a UV sphere of `radius_mm` at the seed.
BalloonMesh start_sphere(const Vec3f& seed_mm, float radius_mm);

class BalloonEvolution {
 public:
  /// S^0: `start` (closed, genus 0, outward: start_sphere, or the warm start's mesh,
  /// warm_start.h), its vertex states as given. A_t starts empty: the previous volume's swept set
  /// is not carried (a withdrawn needle's tunnel must not survive in it), and the start mesh's
  /// interior is not marked either, because the self-intersection test needs the normal of the
  /// front that swept a voxel, which an interior voxel has not got; the start surface itself marks
  /// its band with its normals here, so two sheets that meet again in the new volume see each
  /// other. `smoothed` (Float32), `sampler` and `options` must outlive the object; `stats` receives
  /// the counters and phase times.
  BalloonEvolution(const volume::Volume& smoothed, const ImageSampler& sampler,
                   const BalloonOptions& options, const CostRule& cost, const WallSnap& snap,
                   BalloonMesh start, BalloonStats& stats);

  /// A start that is itself a balloon from before a leak (sealed, leak_seal.h): it is the first
  /// copy kept, so a leak again rolls back to it or to a later one.
  void keep_start_before_leak();

  /// Evolves until every vertex stopped, the evolution stalled, the leak bound, a stop request
  /// or the iteration limit; then the remaining moving vertices get IterationLimit.
  void run(std::stop_token stop);

  /// Ends the run once the balloon crumples (crumpling()), so that it can start again with the
  /// stricter self-intersection test; off unless called.
  void watch_for_crumple() { watch_crumple_ = true; }
  /// The run ended because the balloon crumpled; its result is not to be taken.
  bool crumpled() const { return crumpled_; }

  bool converged() const { return all_stopped_ || stats_.stalled; }
  /// Why the leak bound ended it (empty unless stats.leaked).
  std::string leak_message() const;
  /// The leak bound ended it, and the balloon as it was before the leak began is kept: take_result
  /// gives that one (stats.leak_rollback_iteration says from when).
  bool rolled_back() const { return stats_.leaked && before_leak_.has_value(); }
  /// The balloon and its stop reasons (counted into stats.stop_counts); once, at the end.
  void take_result(Mesh& mesh, std::vector<StopReason>& stop);

  /// The balloon at the remeshing pass with the fewest moving vertices since their number fell a
  /// quarter below its peak: a leak begins where that number turns to grow again.
  struct Snapshot {
    Mesh mesh;
    std::vector<VertexState> states;  // per vertex of `mesh`
    int iteration = 0;
    int moving = 0;
  };
  /// After a rollback: the balloon kept from before the leak, and where the leaked one's vertices
  /// are now (the sealing of the leak compares the two, leak_seal.h).
  const Snapshot& before_leak() const { return *before_leak_; }
  const std::vector<Vec3f>& positions_mm() const { return a_.pos; }

 private:
  // Per vertex and iteration: kMoved if it moved, kMarks as well if it also entered another
  // voxel than the one it last marked A_t from (so it marks its samples again).
  static constexpr std::uint8_t kMoved = 1, kMarks = 2;

  void begin();
  void all_active();
  int iterate();
  bool advance_vertex(std::uint32_t v, const FrontGrid::Reader& reader);
  void ring_sums(std::uint32_t v, const Vec3f& p, Vec3f& centroid, float& curvature) const;
  void settle(std::uint32_t v, const Vec3f& n, bool stopped, float level_wall,
              const Vec3i& target_ijk, bool target_in_volume, const FrontGrid::Reader& reader);
  void compute_normals();
  void mark_front();
  void stage_samples(std::uint32_t v, const FrontGrid::Reader& reader);
  bool stall_test(int now_moving);
  bool swept_nothing_new();
  bool few_moving(int now_moving) const;
  void open_folds();
  bool in_fold(const FrontGrid::Reader& reader, const Vec3f& p, const Vec3f& n) const;
  bool needs_remesh() const;
  void remesh();
  void keep_before_leak(int iteration, int now_moving);
  Snapshot snapshot(int iteration, int moving) const;
  bool leaking(int now_moving) const;
  bool crumpling();

  const volume::Volume& smoothed_;
  const ImageSampler& sampler_;
  const BalloonOptions& options_;
  const CostRule cost_;
  const WallSnap snap_;
  const StepKernel kernel_;
  const RemeshLimits limits_;
  const float stall_mm_;
  const std::size_t max_vertices_;  // the leak bound
  BalloonStats& stats_;

  mesh::Workers workers_;
  BalloonMesh bm_;
  FrontMarks marks_;
  FlatArrays a_;
  // The vertices still moving (k = 1), ascending: every per-iteration loop runs over these only.
  std::vector<std::uint32_t> active_;
  // `active_` as it was after the last remeshing pass: the vertices write_back has to copy.
  std::vector<std::uint32_t> window_;
  std::vector<std::uint8_t> moved_;
  std::vector<Vec3i> pending_;  // A_t samples to mark, slot r + v of vertex v's ring range

  std::optional<Snapshot> before_leak_;
  int peak_moving_ = 0;
  std::size_t start_vertices_ = 0;
  bool sealed_start_ = false;

  bool all_stopped_ = false;
  int fewest_moving_ = std::numeric_limits<int>::max();
  int windows_without_drop_ = 0;
  std::size_t swept_at_window_ = 0;  // |A_t| at the last stall test
  int windows_unswept_ = 0;          // stall windows since |A_t| last grew

  // Per remeshing pass, the vertices and |A_t| after it (the crumple test reads them back).
  struct PassSize {
    std::size_t vertices = 0;
    std::size_t swept = 0;
  };
  std::vector<PassSize> pass_sizes_;
  bool watch_crumple_ = false;
  bool crumpled_ = false;
};

}  // namespace sonomesh::segment::internal
