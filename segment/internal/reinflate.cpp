// The second balloon pass (segment.h, reinflate): from the reconstructed closed surface back to
// the wall, with the first pass's step, stop rule and snap on a fixed connectivity.
#include <algorithm>
#include <stdexcept>
#include <string>

#include "mesh/mesh.h"
#include "mesh/parallel.h"
#include "segment/internal/corner_table.h"
#include "segment/internal/image_sampler.h"
#include "segment/internal/step.h"
#include "segment/internal/stop_rules.h"

namespace sonomesh::segment {
namespace {

using namespace internal;

// Vertex -> incident faces. The pass needs no halfedges: the umbrella's centroid and the normal
// of equation (2) are sums over the incident faces, and the connectivity never changes.
CornerTable vertex_faces(const Mesh& surface) {
  return CornerTable(surface, "reinflate", [](std::uint32_t f, int) { return f; });
}

// The pass's precondition: a closed manifold whose every vertex has faces (an umbrella).
void check_closed(const Mesh& surface, const CornerTable& vf) {
  if (!mesh::is_closed_manifold(surface))
    throw std::invalid_argument("reinflate: the surface is not closed and manifold");
  for (std::uint32_t v = 0; v < surface.vertices.size(); ++v)
    if (vf.degree(v) == 0)
      throw std::invalid_argument("reinflate: vertex " + std::to_string(v) + " has no face");
}

class Reinflation {
 public:
  Reinflation(const volume::Volume& smoothed, const Mesh& surface, const BalloonStats& first_pass,
              const BalloonOptions& options, const ReinflateOptions& pass, BalloonStats& stats);
  void run(std::stop_token stop);
  void take_result(BalloonResult& result);

 private:
  void start();
  void advance_vertex(std::uint32_t v);

  const ImageSampler sampler_;
  const Mesh& surface_;
  const BalloonOptions& options_;
  const ReinflateOptions& pass_;
  const StepKernel kernel_;
  const float max_move_mm_;
  const BalloonStats& first_pass_;
  CostRule cost_;
  WallSnap snap_;
  BalloonStats& stats_;
  mesh::Workers workers_;
  CornerTable vf_;
  std::vector<Vec3f> pos_, next_pos_;
  std::vector<float> cost_of_, floor_of_, path_of_;
  std::vector<StopReason> reason_;
  std::vector<std::uint32_t> active_;  // the vertices still moving
};

Reinflation::Reinflation(const volume::Volume& smoothed, const Mesh& surface,
                         const BalloonStats& first_pass, const BalloonOptions& options,
                         const ReinflateOptions& pass, BalloonStats& stats)
    : sampler_(smoothed),
      surface_(surface),
      options_(options),
      pass_(pass),
      kernel_(options, smoothed, smoothed.spacing_mm().minCoeff()),
      max_move_mm_(pass.max_move_vox * smoothed.spacing_mm().minCoeff()),
      first_pass_(first_pass),
      stats_(stats),
      workers_(options.threads),
      vf_(vertex_faces(surface)),
      pos_(surface.vertices),
      next_pos_(surface.vertices) {
  check_closed(surface, vf_);
  const float vox_mm = smoothed.spacing_mm().minCoeff();
  // The first pass's rule and thresholds: both passes stop at the same level. Except the
  // per-axis rise: it guards the first pass's long paths beside a shadow's edge, while this pass
  // moves at most max_move_vox, where the split's speckle would only hold it back.
  cost_ = CostRule{
      .scale = cost_scale(options.relative_cost, first_pass.tissue_level),
      .tau = first_pass.tau_cost_used,
      .tau_climb = first_pass.tau_climb_used,
      .window_mm = options.cost_window_vox * vox_mm,
      .noise_per_mm = options.noise_allowance ? first_pass.noise_rise_per_mm : 0.0f,
      .region = region_veto(options, vox_mm, first_pass.seed_level, first_pass.tissue_level),
      .level = level_stop(options, vox_mm, first_pass.seed_level, first_pass.tissue_level,
                          kernel_.box_lo, kernel_.box_hi)};
  snap_ = wall_snap(options, vox_mm, first_pass.tissue_level, kernel_.box_lo, kernel_.box_hi);
  stats_.seed_level = first_pass.seed_level;
  stats_.tissue_level = first_pass.tissue_level;
  stats_.tau_cost_used = first_pass.tau_cost_used;
  stats_.tau_climb_used = first_pass.tau_climb_used;
  start();
}

// Each vertex starts as if it had climbed from the seed's level to where it stands, so a vertex
// part-way up the wall climbs only the rest; one already above the first pass's stop level is
// at or past the wall and stays.
void Reinflation::start() {
  const std::size_t nv = pos_.size();
  cost_of_.resize(nv);
  floor_of_.resize(nv);
  path_of_.assign(nv, 0.0f);
  reason_.resize(nv);
  const CostScale& scale = cost_.scale;
  const float seed_level = scale.map(first_pass_.seed_level);
  const float wall_level =
      scale.map(first_pass_.seed_level +
                options_.tau_cost_fraction * (first_pass_.tissue_level - first_pass_.seed_level));
  workers_.parallel_for(nv, kLightGrain, [&](std::size_t b, std::size_t e) {
    for (std::size_t v = b; v < e; ++v) {
      const float level = scale.map(sampler_.value(pos_[v]));
      cost_of_[v] = std::max(0.0f, level - seed_level);
      floor_of_[v] = std::min(level, seed_level);
      reason_[v] = level >= wall_level ? StopReason::Boundary : StopReason::Moving;
    }
  });
  for (std::uint32_t v = 0; v < nv; ++v)
    if (reason_[v] == StopReason::Moving) active_.push_back(v);
}

void Reinflation::advance_vertex(std::uint32_t v) {
  const Vec3f p = pos_[v];
  Vec3f n = Vec3f::Zero(), centroid = Vec3f::Zero();
  for (std::uint32_t i = vf_.begin[v]; i < vf_.begin[v + 1]; ++i) {
    const auto& t = surface_.triangles[vf_.list[i]];
    n += unit_face_normal(pos_, t);  // equation (2)
    for (const std::uint32_t q : t) centroid += pos_[q];
  }
  if (n.norm() > 0.0f) n.normalize();
  // U(P): each of the deg neighbours is in two of the faces, and P itself in all of them.
  const float deg = static_cast<float>(vf_.degree(v));
  const Vec3f d = kernel_.step((centroid - deg * p) / (2.0f * deg) - p, n);
  if (kernel_.outside(p + d)) {
    reason_[v] = StopReason::Boundary;
    return;
  }
  bool stopped = false;
  float level_wall = 0.0f;
  const float t =
      cost_.step(sampler_, p, d, n, cost_of_[v], floor_of_[v], path_of_[v], stopped, level_wall);
  // (Snapped no further ahead than the move bound allows.)
  const float ahead_mm = std::max(0.0f, max_move_mm_ - path_of_[v]);
  next_pos_[v] = !stopped         ? p + t * d
                 : level_wall > 0 ? cost_.level.snap(sampler_, p + t * d, n, level_wall, ahead_mm)
                                  : snap_.apply(sampler_, p + t * d, n, ahead_mm);
  if (stopped)
    reason_[v] = StopReason::Boundary;
  else if (path_of_[v] >= max_move_mm_)
    reason_[v] = StopReason::IterationLimit;  // moved its most
}

void Reinflation::run(std::stop_token stop) {
  int it = 0;
  for (it = 1; it <= pass_.max_iterations && !active_.empty(); ++it) {
    if (stop.stop_requested()) {
      stats_.cancelled = true;
      break;
    }
    workers_.parallel_for(active_.size(), kHeavyGrain, [&](std::size_t b, std::size_t e) {
      for (std::size_t k = b; k < e; ++k) advance_vertex(active_[k]);
    });
    // Every update above read the previous iterate; now they take effect.
    for (const std::uint32_t v : active_) pos_[v] = next_pos_[v];
    std::erase_if(active_, [&](std::uint32_t v) { return reason_[v] != StopReason::Moving; });
  }
  stats_.iterations = std::min(it, pass_.max_iterations);
}

void Reinflation::take_result(BalloonResult& result) {
  for (const std::uint32_t v : active_) reason_[v] = StopReason::IterationLimit;
  result.converged = active_.empty();
  result.mesh.vertices = std::move(pos_);
  result.mesh.triangles = surface_.triangles;
  for (const StopReason r : reason_) ++stats_.stop_counts[static_cast<std::size_t>(r)];
  result.stop = std::move(reason_);
}

}  // namespace

BalloonResult reinflate(const volume::Volume& smoothed_in, const Mesh& surface,
                        const BalloonStats& first_pass, const BalloonOptions& options,
                        const ReinflateOptions& pass, std::stop_token stop) {
  const auto t0 = Clock::now();
  if (smoothed_in.empty()) throw std::invalid_argument("reinflate: empty volume");
  if (!(first_pass.tissue_level > first_pass.seed_level))
    throw std::invalid_argument(
        "reinflate: first_pass holds no seed statistics (a balloon that ran)");
  if (!(pass.max_move_vox > 0.0f) || pass.max_iterations < 1)
    throw std::invalid_argument("reinflate: max_move_vox must be > 0 and max_iterations >= 1");
  check_options(options);
  volume::Volume converted;
  const volume::Volume& smoothed = as_float32(smoothed_in, converted);
  BalloonResult result;
  Reinflation pass2(smoothed, surface, first_pass, options, pass, result.stats);
  pass2.run(std::move(stop));
  pass2.take_result(result);
  result.stats.elapsed_ms = ms_since(t0);
  return result;
}

}  // namespace sonomesh::segment
