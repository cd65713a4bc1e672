#include "daemon/internal/worker.h"

#include <spdlog/spdlog.h>

#include <algorithm>
#include <cmath>
#include <thread>

#include "daemon/internal/outputs.h"
#include "daemon/internal/track.h"

namespace sonomesh::daemon {

using Clock = std::chrono::steady_clock;

namespace {

constexpr auto kPollTimeout = std::chrono::milliseconds(200);
constexpr auto kColdWait = std::chrono::milliseconds(2);

double ms_between(Clock::time_point a, Clock::time_point b) {
  return std::chrono::duration<double, std::milli>(b - a).count();
}

nlohmann::json vec_json(const SeedMm& v) { return {v[0], v[1], v[2]}; }

// Why the volume started as it did: the pipeline's reason for a tracked surface or a refused warm
// start, the worker's for the rest; a tracking the checks refused is named after the start that
// ran instead.
std::string start_reason(const StartDecision& decision, const PipelineResult& result) {
  if (result.tracking.chain > 0) return result.start_reason;
  std::string why = result.warm_start ? decision.reason : result.start_reason;
  if (!result.tracking.refused.empty())
    why += " (surface not tracked: " + result.tracking.refused + ")";
  return why;
}

// The result's journal fields: topology, size, and the quality verdict (DESIGN.md).
void describe_result(const PipelineResult& result, nlohmann::json& line) {
  line["genus"] = result.topology.genus;
  line["components"] = result.topology.components;
  line["watertight"] = result.topology.watertight;
  line["vertices"] = result.topology.vertices;
  line["faces"] = result.topology.faces;
  line["volume_ml"] = result.enclosed_volume_ml;
  line["balloon_iterations"] = result.balloon_iterations;
  line["target"] = to_string(result.target);
  line["quality"] = result.quality_ok ? "ok" : "suspect";
  line["quality_reasons"] = result.quality_reasons;
  line["stop_rule"] = result.stop_rule;
  line["second_opinion"] = result.second_opinion;
}

// The chain's length at which its anchor is refreshed (refresh_anchor): two volumes before the
// length, so that the balloon's result (150-200 ms on one core) is there before the chain reaches
// it; a chain tracked on past its length drifted until the open patch refused it (at 20/s cold
// starts in two daemon_bench runs of three). Four volumes before: a refresh then fell on a volume
// whose balloon came out suspect, and every cold start after it did too.
int refresh_chain(int chain_length) {
  constexpr int kRefreshLead = 2;
  return std::max(1, chain_length - kRefreshLead);
}

}  // namespace

Worker::Worker(RunContext context, VolumeQueue& in, ResultQueue& out,
               std::optional<SeedMm> phantom_seed_mm, std::stop_token abort)
    : context_(std::move(context)),
      in_(in),
      out_(out),
      phantom_seed_mm_(phantom_seed_mm),
      abort_(std::move(abort)) {}

void Worker::override_seed(const SeedMm& seed_mm) {
  std::lock_guard lock(override_mutex_);
  override_mm_ = seed_mm;
}

bool Worker::override_waiting() {
  std::lock_guard lock(override_mutex_);
  return override_mm_.has_value();
}

void Worker::run(int lane, int lanes) {
  PipelineBuffers buffers;  // smoothing buffers, reused from volume to volume
  while (true) {
    if (turn_hook_ && lane == 0) turn_hook_();  // web: the systemd watchdog, from this loop
    auto item = in_.pop(kPollTimeout);
    context_.stats.set_queue_depth(in_.size(), in_.capacity());
    if (!item) {
      if (in_.closed() && in_.size() == 0) break;
      continue;
    }
    const bool cold = claim_cold_start();
    try {
      process(std::move(*item), buffers, cold ? 1 : lanes);
    } catch (const std::exception& e) {
      context_.fatal(e.what());  // the journal cannot be written: nothing sensible can continue
    }
    if (cold) {
      std::lock_guard lock(state_mutex_);
      cold_lane_busy_ = false;
    }
  }
}

// With nothing warm to start from, one lane at a time starts cold, with both cores; another with a
// volume in hand waits for its result (two cold starts at once took 700 ms each at 20 volumes/s,
// as each halved the other's cores). Returns whether this lane took the cold start.
bool Worker::claim_cold_start() {
  for (;;) {
    {
      std::lock_guard lock(state_mutex_);
      if (previous_) return false;
      if (!cold_lane_busy_) return cold_lane_busy_ = true;
    }
    std::this_thread::sleep_for(kColdWait);
  }
}

void Worker::fail(const QueuedVolume& item, const std::string& reason, nlohmann::json line) {
  const std::uint64_t seq = item.raw.sequence;
  {
    std::lock_guard lock(state_mutex_);
    if (!state_sequence_ || seq >= *state_sequence_) {
      previous_.reset();  // the next volume starts cold
      previous_dropped_ = "sequence " + std::to_string(seq) + " failed";
      state_sequence_ = seq;
    }
  }
  line["reason"] = reason;
  line["latency_ms"] = ms_between(item.received, Clock::now());
  context_.recorder.record(seq, JournalStatus::Failed, std::move(line), item.epoch);
  context_.stats.set_last_error("sequence " + std::to_string(seq) + ": " + reason);
  spdlog::warn("sequence {} failed: {}", seq, reason);
}

// The operator's seeds (POST /seed, TOML/CLI seed_mm) are world mm; the pipeline, the phantom's
// seed and the tracked seed (the pipeline's deepest interior point) are in the grid frame. The
// journal and /status say world mm, as the operator gave them.
std::optional<SeedCandidate> Worker::pick_seed(const volume::Volume& input, const RunConfig& config,
                                               nlohmann::json& line) {
  const auto to_grid = [&](const std::optional<SeedMm>& world) -> std::optional<SeedMm> {
    if (!world) return std::nullopt;
    const Vec3f g =
        internal::seed_world_to_grid_mm(input, Vec3f((*world)[0], (*world)[1], (*world)[2]));
    return SeedMm{g.x(), g.y(), g.z()};
  };
  const auto to_world = [&](const SeedMm& grid) {
    const Vec3f w = input.grid_to_world_mm(Vec3f(grid[0], grid[1], grid[2]));
    return SeedMm{w.x(), w.y(), w.z()};
  };
  SeedInputs inputs;
  {
    std::lock_guard lock(override_mutex_);
    inputs.override_mm = to_grid(std::exchange(override_mm_, std::nullopt));
  }
  seed_overridden_ = inputs.override_mm.has_value();
  inputs.configured_mm = to_grid(config.seed_mm);
  inputs.phantom_mm = phantom_seed_mm_;
  const Vec3f centre = input.index_to_mm((input.dims() - Vec3i::Ones()).cast<float>() * 0.5f);
  inputs.centre_mm = {centre.x(), centre.y(), centre.z()};
  const SeedChoice choice = choose_seed(seeds_.candidates(inputs), [&](const SeedMm& mm) {
    return check_seed(input, Vec3f(mm[0], mm[1], mm[2]));
  });
  nlohmann::json refused = nlohmann::json::array();
  for (const auto& [c, why] : choice.refused) {
    refused.push_back(
        {{"origin", to_string(c.origin)}, {"seed_mm", vec_json(to_world(c.mm))}, {"why", why}});
  }
  if (!refused.empty()) line["seeds_refused"] = refused;
  if (choice.chosen) {
    const SeedMm world = to_world(choice.chosen->mm);
    line["seed_mm"] = vec_json(world);
    line["seed_origin"] = to_string(choice.chosen->origin);
    context_.stats.set_seed(world, to_string(choice.chosen->origin));
  }
  return choice.chosen;
}

// The seed, the start and the configuration, from the state the newest result left. A second
// lane gets one core of its own (a lane's parallel loops gained nothing over one thread at
// 20 volumes/s: docs/results.md).
std::optional<Worker::Start> Worker::begin_volume(const volume::Volume& input, int lanes,
                                                  nlohmann::json& line) {
  Start start{.config = context_.config.snapshot(),
              .seed = {},
              .decision = {},
              .warm = {},
              .anchor = 0,
              .anchor_note = {},
              .chain_length = 0};
  if (lanes > 1) {
    if (start.config.pipeline.balloon.threads == 0) start.config.pipeline.balloon.threads = 1;
    start.config.pipeline.poisson.fft_threads = 1;
  }
  std::lock_guard lock(state_mutex_);
  const std::optional<SeedCandidate> seed = pick_seed(input, start.config, line);
  if (!seed) return std::nullopt;
  start.seed = *seed;
  start.decision = choose_start(input, *seed);
  if (seed_overridden_) {  // a new object: no motion to carry, no result of the old one kept
    last_centroid_mm_.reset();
    ++anchor_;
  }
  start.warm = take_warm_start(input, start.decision);
  start.anchor = anchor_;
  if (start.warm && previous_) start.anchor_note = previous_->note;
  // While a lane refreshes the anchor, the chain runs on past its length rather than start cold.
  start.chain_length = start.config.pipeline.track_max_chain;
  if (refresh_busy_) start.config.pipeline.track_max_chain *= 2;
  return start;
}

void Worker::process(QueuedVolume item, PipelineBuffers& buffers, int lanes) {
  const std::uint64_t seq = item.raw.sequence;
  const double queue_wait_ms = ms_between(item.received, Clock::now());
  volume::Volume input;
  try {
    input = volume::Volume::from_raw(item.raw);
  } catch (const std::exception& e) {
    return fail(item, std::string("bad volume: ") + e.what(), nlohmann::json::object());
  }
  item.raw.voxels = {};  // the Volume holds its own copy

  nlohmann::json line = nlohmann::json::object();
  const std::optional<Start> start = begin_volume(input, lanes, line);
  if (!start) {
    const std::string why = line["seeds_refused"].back()["why"].get<std::string>();
    return fail(item, "no usable seed: " + why, std::move(line));
  }
  const Vec3f seed_mm(start->seed.mm[0], start->seed.mm[1], start->seed.mm[2]);
  PipelineResult result;
  try {
    result = run_pipeline(input, seed_mm, start->config.pipeline, buffers,
                          start->warm ? &*start->warm : nullptr, abort_);
  } catch (const std::exception& e) {
    return fail(item, std::string("pipeline: ") + e.what(), std::move(line));
  }
  if (!start->decision.warm) result.start_reason = start->decision.reason;
  line["start"] = result.warm_start ? "warm" : "cold";
  line["start_reason"] = start_reason(start->decision, result);
  nlohmann::json& timings = line["timings_ms"];
  timings["queue_wait"] = queue_wait_ms;
  for (const auto& [stage, ms] : result.timings.stages()) timings[stage] = ms;
  timings["total"] = result.timings.total_ms;
  if (!result.ok) {
    const bool aborted = abort_.stop_requested();
    return fail(item, aborted ? "shutdown: aborted by a second signal" : result.error,
                std::move(line));
  }
  // The labels go to the outputs only: kept with the result for the next volume, they were
  // copied (a volume's size) to be dropped.
  std::optional<volume::Volume> labels = std::move(result.labels);
  const std::optional<WarmStart> refresh_from = end_volume(seq, input, *start, result);
  if (!start->anchor_note.empty())  // (this volume started from a refreshed anchor)
    line["start_reason"] =
        line["start_reason"].get<std::string>() + " (" + start->anchor_note + ")";
  describe_result(result, line);
  context_.stats.count_start(result.warm_start);

  WorkerResult out;
  ProcessedVolume& v = out.volume;
  v.sequence = seq;
  v.epoch = item.epoch;
  v.received = item.received;
  v.report = report_json(result, "sequence " + std::to_string(seq), input, seed_mm);
  v.report["sequence"] = seq;
  v.report["seed_origin"] = to_string(start->seed.origin);
  v.report["queue_wait_ms"] = queue_wait_ms;
  v.report["start_reason"] = line["start_reason"];
  // The outputs are in the input's world frame (LPS mm, DESIGN.md "Geometry and files"): the
  // mesh mapped there, the labels given the input's direction (they share its grid and origin).
  v.mesh = internal::mesh_to_world(result.mesh, input);
  v.labels = std::move(labels);
  if (v.labels) v.labels->set_direction(input.direction());
  v.timings = result.timings;
  v.seed_grid_mm = seed_mm;
  v.input = std::make_shared<const volume::Volume>(std::move(input));
  const std::shared_ptr<const volume::Volume> kept_input = v.input;
  out.line = std::move(line);
  out_.push(std::move(out));
  if (refresh_from) refresh_anchor(seq, *kept_input, *start, seed_mm, *refresh_from, buffers);
}

// Near the chain's length (refresh_chain) the balloon segments the volume just published once
// more, its tracked result already out: the tracked surface drifts where the wall is faint (in
// the needle's shadow +5 % of the volume over 30 volumes at 10/s) and this result re-anchors the
// chain, while the other lane tracks on and no volume waits for a cold start. Where it may not
// anchor the chain (unfit_anchor: suspect, failed, another genus), the next volume starts cold.
// The pipeline runs it as the cold start after a chain (its length set to `tracked`'s chain).
void Worker::refresh_anchor(std::uint64_t sequence, const volume::Volume& input, const Start& start,
                            const Vec3f& seed_mm, const WarmStart& tracked,
                            PipelineBuffers& buffers) {
  PipelineConfig config = start.config.pipeline;
  config.want_labels = false;
  config.track_max_chain = tracked.previous->tracking.chain;
  const int tracked_genus = tracked.previous->topology.genus;
  PipelineResult fresh;
  try {
    fresh = run_pipeline(input, seed_mm, config, buffers, &tracked, abort_);
  } catch (const std::exception& e) {
    fresh.ok = false;
    fresh.error = e.what();
  }
  std::lock_guard lock(state_mutex_);
  refresh_busy_ = false;
  if (anchor_ != start.anchor) return;  // the operator chose another object meanwhile
  ++anchor_;
  if (const std::string why = internal::unfit_anchor(fresh, tracked_genus); !why.empty()) {
    previous_.reset();
    previous_dropped_ =
        "the balloon's refresh on sequence " + std::to_string(sequence) + " was " + why;
    spdlog::warn("sequence {}: the balloon's refresh was {}; the next volume starts cold", sequence,
                 why);
    return;
  }
  keep_for_warm_start(input, fresh);
  previous_->note = "re-anchored by the balloon on sequence " + std::to_string(sequence);
  spdlog::debug("sequence {}: anchor refreshed in {:.0f} ms", sequence, fresh.timings.total_ms);
}

// A result older than the state's (the other lane's newer volume finished first) is still
// checked against it for a genus change, but does not set it back, nor does one begun before the
// anchor was refreshed. Returns the warm start kept when this lane is to refresh the anchor near
// the chain's length (refresh_anchor).
std::optional<WarmStart> Worker::end_volume(std::uint64_t sequence, const volume::Volume& input,
                                            const Start& start, PipelineResult& result) {
  std::lock_guard lock(state_mutex_);
  const bool newest = !state_sequence_ || sequence >= *state_sequence_;
  // (A cold start after a refused tracking, or after a tracked chain, leaves a fresh result to
  // track from: not a refused warm start.)
  const bool refused = start.decision.warm && !result.warm_start &&
                       result.tracking.refused.empty() && !result.tracking.balloon_stale;
  since_refused_ = refused ? 0 : std::min(since_refused_, 1 << 29) + 1;
  flag_genus_change(start.seed, result, newest);
  if (!newest) return std::nullopt;
  state_sequence_ = sequence;
  std::optional<SeedMm> deepest;
  if (result.deepest_interior_mm) {
    const Vec3f& d = *result.deepest_interior_mm;
    deepest = SeedMm{d.x(), d.y(), d.z()};
  }
  seeds_.on_result(deepest, override_waiting());
  if (start.anchor != anchor_) return std::nullopt;
  keep_for_warm_start(input, result);
  // (The configured length: this volume's own may have been doubled while another lane was busy.)
  if (!previous_ || refresh_busy_ || !result.quality_ok ||
      result.tracking.chain < refresh_chain(start.chain_length))
    return std::nullopt;
  refresh_busy_ = true;
  return previous_->warm;
}

// The previous warm start, copied (another lane may start from it too); this volume's result
// replaces it. The inset: 3 voxels, plus how far the object moved last time (it may move as far
// again); at 2 voxels warm volumes drifted from the truth (docs/tuning.md).
std::optional<WarmStart> Worker::take_warm_start(const volume::Volume& input,
                                                 const StartDecision& start) {
  if (!start.warm || !previous_) return std::nullopt;
  const float vox_mm = input.spacing_mm().minCoeff();
  WarmStart warm = previous_->warm;
  warm.inset_mm = (3.0f + previous_->motion_vox) * vox_mm;
  return warm;
}

// A tracked object whose genus changed since the last result is flagged "genus changed": a needle
// went in or came out, or one of the two results has the wrong topology (an extra handle is ok to
// the verdict otherwise, docs/results.md). Either way a reader should look. Another seed is
// another object.
void Worker::flag_genus_change(const SeedCandidate& seed, PipelineResult& result, bool newest) {
  if (seed.origin == SeedOrigin::Tracked && last_genus_ && *last_genus_ != result.topology.genus) {
    result.quality_ok = false;
    result.quality_reasons.emplace_back("genus changed");
  }
  if (newest) last_genus_ = result.topology.genus;
}

// Cold unless the last result can start this one (seed_policy.h, decide_start).
StartDecision Worker::choose_start(const volume::Volume& input, const SeedCandidate& seed) const {
  StartInputs in;
  in.seed_overridden = seed_overridden_;
  in.have_previous = previous_.has_value();
  in.seed_tracked = seed.origin == SeedOrigin::Tracked;
  if (previous_) {
    in.previous_quality_ok = previous_->quality_ok;
    in.same_grid =
        previous_->dims == input.dims() && previous_->spacing_mm.isApprox(input.spacing_mm()) &&
        (previous_->origin_mm - input.origin_mm()).norm() < 0.01f * input.spacing_mm().minCoeff();
    in.motion_vox = previous_->motion_vox;
    in.volume_change = previous_->volume_change;
  }
  in.since_refused = since_refused_;
  in.previous_dropped = previous_dropped_;
  return decide_start(in);
}

// The warm start (the balloon, genus 0 by construction, and the result whose surface may be
// tracked), where the result's centre is, how large it is, and how much both changed since the
// result before.
void Worker::keep_for_warm_start(const volume::Volume& input, const PipelineResult& result) {
  if (result.balloon.vertices.empty() || result.mesh.vertices.empty()) return;
  Previous next;
  for (const Vec3f& p : result.mesh.vertices) next.centroid_mm += p;
  next.centroid_mm /= static_cast<float>(result.mesh.vertices.size());
  next.volume_ml = result.enclosed_volume_ml;
  next.dims = input.dims();
  next.spacing_mm = input.spacing_mm();
  next.origin_mm = input.origin_mm();
  next.quality_ok = result.quality_ok;
  if (last_centroid_mm_) {
    next.motion_vox =
        (next.centroid_mm - *last_centroid_mm_).norm() / input.spacing_mm().minCoeff();
    next.volume_change =
        last_volume_ml_ > 0.0
            ? static_cast<float>(std::abs(next.volume_ml - last_volume_ml_) / last_volume_ml_)
            : 1.0f;
  }
  last_centroid_mm_ = next.centroid_mm;
  last_volume_ml_ = next.volume_ml;
  next.warm = warm_start_from(result, 0.0f);
  previous_ = std::move(next);
  previous_dropped_.clear();
}

}  // namespace sonomesh::daemon
