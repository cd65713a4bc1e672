#include "daemon/internal/live_runner.h"

#include <algorithm>
#include <cmath>
#include <deque>
#include <stdexcept>
#include <thread>

#include <unistd.h>

#include <spdlog/spdlog.h>

#include "daemon/internal/atomic_file.h"
#include "reconstruct/reconstruct.h"
#include "volume/volume.h"

namespace sonomesh::daemon {

namespace fs = std::filesystem;
using Clock = std::chrono::steady_clock;
using acquire::AcquireError;

namespace {

constexpr auto kPollTimeout = std::chrono::milliseconds(200);
// A repeated sequence this close below the highest one seen is a resend (dropped: it already has
// its line); further back, or 0, means the probe restarted its counter (new journal epoch).
constexpr std::uint64_t kResendWindow = 16;

double ms_between(Clock::time_point a, Clock::time_point b) {
  return std::chrono::duration<double, std::milli>(b - a).count();
}

std::string stem_of(std::uint64_t sequence, std::uint64_t epoch) {
  return epoch == 0 ? std::to_string(sequence)
                    : "e" + std::to_string(epoch) + "-" + std::to_string(sequence);
}

nlohmann::json vec_json(const std::array<float, 3>& v) { return {v[0], v[1], v[2]}; }

}  // namespace

const char* to_string(SeedOrigin origin) {
  switch (origin) {
    case SeedOrigin::Tracked: return "tracked";
    case SeedOrigin::Configured: return "configured";
    case SeedOrigin::Phantom: return "phantom";
    case SeedOrigin::Centre: return "centre";
  }
  return "unknown";
}

// ---------------------------------------------------------------------------------------------
// Worker -> writer hand-over.

struct LiveRunner::WriteJob {
  std::uint64_t sequence = 0;
  std::uint64_t epoch = 0;
  Clock::time_point received;
  segment::Mesh mesh;
  nlohmann::json report;
  nlohmann::json line;  // journal fields gathered by the worker
  StageTimings timings;
};

class LiveRunner::WriteQueue {
 public:
  // Small: meshes are a few MB at most; if the disk stalls, the worker waits rather than piling
  // up results in memory.
  static constexpr std::size_t kCapacity = 4;

  void push(WriteJob job) {
    std::unique_lock lock(mutex_);
    not_full_.wait(lock, [&] { return items_.size() < kCapacity; });
    items_.push_back(std::move(job));
    not_empty_.notify_one();
  }
  std::optional<WriteJob> pop() {
    std::unique_lock lock(mutex_);
    not_empty_.wait(lock, [&] { return closed_ || !items_.empty(); });
    if (items_.empty()) return std::nullopt;
    WriteJob job = std::move(items_.front());
    items_.pop_front();
    not_full_.notify_one();
    return job;
  }
  void close() {
    std::lock_guard lock(mutex_);
    closed_ = true;
    not_empty_.notify_all();
  }

 private:
  std::mutex mutex_;
  std::condition_variable not_empty_, not_full_;
  std::deque<WriteJob> items_;
  bool closed_ = false;
};

// ---------------------------------------------------------------------------------------------

LiveRunner::LiveRunner(RunConfig config, std::unique_ptr<acquire::Source> source,
                       SourceFactory factory, bool live,
                       std::optional<std::array<float, 3>> phantom_seed_mm)
    : config_(std::move(config)),
      source_(std::move(source)),
      factory_(std::move(factory)),
      live_(live),
      phantom_seed_mm_(phantom_seed_mm),
      out_(config_.out) {
  source_ready_ = source_ != nullptr;
  std::error_code ec;
  for (const fs::path& dir : {out_, out_ / "meshes", out_ / "reports"}) {
    fs::create_directories(dir, ec);
    if (ec) throw std::runtime_error("cannot create " + dir.string() + ": " + ec.message());
  }
  int stale = 0;
  for (const fs::path& dir : {out_, out_ / "meshes", out_ / "reports"}) {
    stale += remove_stale_temporaries(dir);
  }
  if (stale > 0) spdlog::warn("removed {} temporary file(s) left by an earlier run", stale);
  journal_ = std::make_unique<Journal>(out_ / "journal.jsonl");
  events_ = std::make_unique<JsonlFile>(out_ / "events.jsonl");
  // A restart on the same out dir goes on where the journal ends (same epoch, same sequences).
  epoch_ = journal_->epoch();
  highest_sequence_ = journal_->highest_before();
  resume_gap_pending_ = live_ && highest_sequence_.has_value();
  // What a killed earlier run had in hand (received, no line yet) a live probe will not send
  // again; replay sends it again and it is processed then.
  if (live_) {
    for (const auto& [first, count] : journal_->holes_before()) {
      stats_.count(JournalStatus::Lost,
                   journal_->write_lost(first, count, "in hand when an earlier run stopped"));
    }
  }
  queue_ = std::make_unique<VolumeQueue>(
      config_.queue_capacity, live_ ? VolumeQueue::Mode::KeepNewest : VolumeQueue::Mode::Block);
  write_queue_ = std::make_unique<WriteQueue>();
  stats_.set_source(config_.source, live_);
  stats_.set_queue_depth(0, config_.queue_capacity);
  stats_.set_source_state(source_ ? SourceState::Connected : SourceState::Connecting);
  if (config_.seed_mm) {
    stats_.set_seed(config_.seed_mm, to_string(SeedOrigin::Configured));
  } else if (phantom_seed_mm_) {
    stats_.set_seed(phantom_seed_mm_, to_string(SeedOrigin::Phantom));
  } else {
    stats_.set_seed(std::nullopt, to_string(SeedOrigin::Centre));
  }
}

LiveRunner::~LiveRunner() = default;

RunConfig LiveRunner::config_snapshot() const {
  std::lock_guard lock(config_mutex_);
  return config_;
}

void LiveRunner::event(const std::string& kind, nlohmann::json fields) {
  if (!fields.is_object()) fields = nlohmann::json::object();
  fields["event"] = kind;
  try {
    events_->append(std::move(fields));
  } catch (const std::exception& e) {
    spdlog::error("{}", e.what());
  }
}

void LiveRunner::fail_fatal(const std::string& what) {
  spdlog::critical("{}; stopping", what);
  stats_.set_last_error(what);
  fatal_ = true;
  request_stop();
}

void LiveRunner::request_stop() {
  if (stopping_.exchange(true)) {
    abort_.request_stop();  // second request: give up the volume in hand too
  }
  if (source_ready_) {
    std::lock_guard lock(source_mutex_);
    if (source_) source_->interrupt();
  }
  // Wakes a replay push() blocked on a full queue; what is queued is journaled by the
  // acquisition thread as it leaves.
  stop_cv_.notify_all();
  {
    std::vector<QueuedVolume> left = queue_->abort();
    for (const QueuedVolume& item : left) journal_skipped(item, "shutdown");
  }
}

void LiveRunner::reload(const RunConfig& next) {
  RunConfig previous = config_snapshot();
  if (next.source != previous.source || next.out != previous.out ||
      next.http_address != previous.http_address || next.record_path != previous.record_path) {
    spdlog::warn("config reload: source, out, http and record_path changes need a restart; "
                 "keeping the running ones");
  }
  RunConfig applied = next;
  applied.source = previous.source;
  applied.out = previous.out;
  applied.http_address = previous.http_address;
  applied.record_path = previous.record_path;
  {
    std::lock_guard lock(config_mutex_);
    config_ = applied;
  }
  queue_->set_capacity(applied.queue_capacity);
  stats_.set_queue_depth(queue_->size(), applied.queue_capacity);
  if (applied.seed_mm != previous.seed_mm) {
    std::lock_guard lock(seed_mutex_);
    override_seed_mm_ = applied.seed_mm;
  }
  spdlog::set_level(spdlog::level::from_str(applied.log_level));
  spdlog::info("configuration reloaded; applies from the next volume");
  event("config_reloaded");
}

std::optional<std::string> LiveRunner::set_seed(const std::array<float, 3>& seed_mm) {
  {
    std::lock_guard lock(seed_mutex_);
    override_seed_mm_ = seed_mm;
  }
  {
    std::lock_guard lock(config_mutex_);
    config_.seed_mm = seed_mm;  // also the fallback from now on
  }
  stats_.set_seed(seed_mm, to_string(SeedOrigin::Configured));
  spdlog::info("seed set to ({:.2f}, {:.2f}, {:.2f}) mm; used from the next volume", seed_mm[0],
               seed_mm[1], seed_mm[2]);
  event("seed_set", {{"seed_mm", vec_json(seed_mm)}});
  return std::nullopt;
}

void LiveRunner::journal_skipped(const QueuedVolume& item, const std::string& reason,
                                 nlohmann::json extra) {
  if (!extra.is_object()) extra = nlohmann::json::object();
  extra["reason"] = reason;
  extra["received_age_ms"] = ms_between(item.received, Clock::now());
  try {
    journal_->write(item.raw.sequence, JournalStatus::Skipped, std::move(extra), item.epoch);
    stats_.count(JournalStatus::Skipped);
  } catch (const std::exception& e) {
    fail_fatal(e.what());
  }
  spdlog::debug("sequence {} skipped ({})", item.raw.sequence, reason);
}

// ---------------------------------------------------------------------------------------------
// Threads.

int LiveRunner::run() {
  event("started", {{"source", config_.source},
                    {"live", live_},
                    {"queue_capacity", config_.queue_capacity},
                    {"pid", static_cast<long long>(::getpid())}});
  if (source_) event("source_opened", {{"source", source_->describe()}});
  std::thread writer([this] { writer_loop(); });
  std::thread worker([this] { worker_loop(); });
  acquisition_loop();  // on the calling thread
  worker.join();
  write_queue_->close();
  writer.join();
  {
    std::lock_guard lock(source_mutex_);
    source_.reset();
  }
  const nlohmann::json counts = stats_.status_json()["volumes"];
  spdlog::info("stopped: {}", counts.dump());
  event("stopped", {{"volumes", counts}, {"reason", stopping_ ? "signal" : "end of stream"}});
  return fatal_ ? 1 : 0;
}

void LiveRunner::acquisition_loop() {
  auto backoff = std::chrono::milliseconds(50);
  while (!stopping_) {
    if (!source_ready_) {
      auto opened = factory_();
      if (!opened) {
        stats_.set_last_error(acquire::to_string(opened.error()));
        if (!outage_started_) {
          outage_started_ = Clock::now();
          spdlog::warn("source {} not available ({}); retrying", config_.source,
                       acquire::to_string(opened.error()));
          event("source_unavailable", {{"error", acquire::to_string(opened.error())}});
        }
        std::unique_lock lock(stop_mutex_);
        stop_cv_.wait_for(lock, backoff, [&] { return stopping_.load(); });
        backoff = std::min(backoff * 2, std::chrono::milliseconds(500));
        continue;
      }
      {
        std::lock_guard lock(source_mutex_);
        source_ = std::move(*opened);
      }
      source_ready_ = true;
      if (stopping_) source_->interrupt();
      backoff = std::chrono::milliseconds(50);
      spdlog::info("source {} opened", source_->describe());
      event("source_opened", {{"source", source_->describe()}});
    }
    auto next = source_->next(kPollTimeout);
    if (next) {
      const Clock::time_point received =
          next->received == Clock::time_point{} ? Clock::now() : next->received;
      handle_volume(std::move(*next), received);
      continue;
    }
    if (next.error().code == AcquireError::Code::EndOfStream) {
      stats_.set_source_state(SourceState::Ended);
      spdlog::info("end of stream from {}; draining", config_.source);
      event("end_of_stream");
      queue_->close();
      return;
    }
    handle_error(next.error());
  }
  // Stopped by a signal: whatever is still queued is accounted for as skipped.
  for (const QueuedVolume& item : queue_->abort()) journal_skipped(item, "shutdown");
}

void LiveRunner::handle_volume(acquire::RawVolume raw, Clock::time_point received) {
  if (stats_.source_state() != SourceState::Connected) {
    stats_.set_source_state(SourceState::Connected);
    if (outage_started_) {
      const double outage_ms = ms_between(*outage_started_, Clock::now());
      spdlog::info("source {} is back after {:.0f} ms", config_.source, outage_ms);
      event("source_reconnected", {{"outage_ms", outage_ms}});
      outage_started_.reset();
    }
  }
  const std::uint64_t seq = raw.sequence;
  if (done_by_earlier_run(seq)) return;
  if (!journal_->claim(seq)) {
    const bool resend = highest_sequence_ && seq != 0 && seq + kResendWindow > *highest_sequence_;
    if (resend) {
      spdlog::warn("sequence {} received again; dropped (it already has its journal line)", seq);
      event("duplicate_sequence", {{"sequence", seq}});
      return;
    }
    epoch_ = journal_->new_epoch();
    spdlog::warn("sequence went back from {} to {}: the probe restarted its counter; journal "
                 "epoch {}", highest_sequence_ ? *highest_sequence_ : 0, seq, epoch_);
    event("sequence_restart", {{"from", highest_sequence_ ? *highest_sequence_ : 0},
                               {"to", seq},
                               {"epoch", epoch_}});
    journal_->claim(seq);
    highest_sequence_ = seq;
  }
  highest_sequence_ = std::max(highest_sequence_.value_or(seq), seq);
  QueuedVolume item{std::move(raw), received, epoch_};
  for (const QueuedVolume& old : queue_->push(std::move(item))) {
    if (old.raw.sequence == seq && old.epoch == epoch_ && queue_->closed()) {
      journal_skipped(old, "shutdown");
    } else {
      journal_skipped(old, "superseded", {{"superseded_by", seq}});
    }
  }
  stats_.set_queue_depth(queue_->size(), queue_->capacity());
}

// A restart on an out dir that has a journal. Replay delivers the same sequences again: those
// with a line from the earlier run are dropped (counted, logged once). A live probe went on while
// the daemon was down: the sequences between the journal's last and the first one now received
// get `lost` lines, as a gap reported by the source would.
bool LiveRunner::done_by_earlier_run(std::uint64_t seq) {
  if (!live_ && journal_->written_before(seq)) {
    if (earlier_done_++ == 0) {
      spdlog::info("replay: sequence {} and any others with a journal line from an earlier run "
                   "are not processed again", seq);
    }
    return true;
  }
  if (!resume_gap_pending_) return false;
  resume_gap_pending_ = false;
  const std::uint64_t last = *journal_->highest_before();
  if (seq <= last + 1) return false;  // no gap, or the probe restarted too (a new epoch)
  handle_error(AcquireError{AcquireError::Code::Lost, 0,
                            "not received while the daemon was not running", last + 1,
                            seq - last - 1});
  return false;
}

void LiveRunner::handle_error(const AcquireError& error) {
  const RunConfig config = config_snapshot();
  switch (error.code) {
    case AcquireError::Code::Timeout:
      return;
    case AcquireError::Code::Lost: {
      if (error.count > config.max_lost_lines) {
        spdlog::warn("sequence jumped by {} from {}: more than max_lost_lines, recorded as an "
                     "event only", error.count, error.sequence.value_or(0));
        event("sequence_jump", {{"first_missing", error.sequence.value_or(0)},
                                {"count", error.count}});
        return;
      }
      try {
        const std::uint64_t n =
            journal_->write_lost(error.sequence.value_or(0), error.count, "sequence gap");
        stats_.count(JournalStatus::Lost, n);
        if (n > 0) spdlog::warn("{} volume(s) lost upstream from sequence {}", n, *error.sequence);
      } catch (const std::exception& e) {
        fail_fatal(e.what());
      }
      return;
    }
    case AcquireError::Code::BadRecord:
    case AcquireError::Code::Incomplete: {
      const std::string reason = std::string(acquire::to_string(error.code)) + ": " + error.detail;
      std::optional<std::uint64_t> seq = error.sequence;
      if (seq && !journal_->claim(*seq)) {
        spdlog::warn("dropped record for sequence {} which already has a line: {}", *seq, reason);
        event("duplicate_rejected", {{"sequence", *seq}, {"reason", reason}});
        return;
      }
      if (seq) highest_sequence_ = std::max(highest_sequence_.value_or(*seq), *seq);
      try {
        journal_->write(seq, JournalStatus::Rejected, {{"reason", reason}}, epoch_);
        stats_.count(JournalStatus::Rejected);
      } catch (const std::exception& e) {
        fail_fatal(e.what());
      }
      stats_.set_last_error(reason);
      spdlog::warn("rejected record{}: {}", seq ? " " + std::to_string(*seq) : std::string(),
                   reason);
      return;
    }
    case AcquireError::Code::Disconnected:
    case AcquireError::Code::NotFound:
    case AcquireError::Code::IoError: {
      stats_.set_last_error(acquire::to_string(error));
      if (stats_.source_state() != SourceState::Reconnecting) {
        stats_.set_source_state(SourceState::Reconnecting);
        stats_.count_outage();
        outage_started_ = Clock::now();
        spdlog::warn("source lost: {}; reconnecting", acquire::to_string(error));
        event("source_lost", {{"error", acquire::to_string(error)}});
      }
      if (error.code != AcquireError::Code::Disconnected) {
        // The source did not wait itself; do not spin.
        std::unique_lock lock(stop_mutex_);
        stop_cv_.wait_for(lock, std::chrono::milliseconds(100), [&] { return stopping_.load(); });
      }
      return;
    }
    case AcquireError::Code::EndOfStream:
      return;  // handled by the caller
    case AcquireError::Code::InvalidArgument:
      fail_fatal("source: " + acquire::to_string(error));
      return;
  }
}

void LiveRunner::worker_loop() {
  while (true) {
    if (hooks_.worker_turn) hooks_.worker_turn();  // web hook: systemd watchdog from this loop
    auto item = queue_->pop(kPollTimeout);
    stats_.set_queue_depth(queue_->size(), queue_->capacity());
    if (!item) {
      if (queue_->closed() && queue_->size() == 0) return;
      continue;
    }
    try {
      process_one(std::move(*item));
    } catch (const std::exception& e) {
      // Output or journal failures: nothing sensible can continue.
      fail_fatal(e.what());
    }
  }
}

void LiveRunner::process_one(QueuedVolume item) {
  const RunConfig config = config_snapshot();
  const std::uint64_t seq = item.raw.sequence;
  const Clock::time_point started = Clock::now();
  const double queue_wait_ms = ms_between(item.received, started);

  auto fail = [&](const std::string& reason, nlohmann::json extra) {
    extra["reason"] = reason;
    extra["latency_ms"] = ms_between(item.received, Clock::now());
    journal_->write(seq, JournalStatus::Failed, std::move(extra), item.epoch);
    stats_.count(JournalStatus::Failed);
    stats_.set_last_error("sequence " + std::to_string(seq) + ": " + reason);
    spdlog::warn("sequence {} failed: {}", seq, reason);
  };

  volume::Volume input;
  try {
    input = volume::Volume::from_raw(item.raw);
  } catch (const std::exception& e) {
    fail(std::string("bad volume: ") + e.what(), nlohmann::json::object());
    return;
  }
  item.raw.voxels = {};  // the Volume holds its own copy

  // Seed: the previous result's deepest point, else the configured one (a POST /seed first), else
  // the phantom's, else the volume centre; the first that check_seed accepts wins.
  struct Candidate {
    std::array<float, 3> mm;
    SeedOrigin origin;
  };
  std::vector<Candidate> candidates;
  {
    std::lock_guard lock(seed_mutex_);
    if (override_seed_mm_) {
      candidates.push_back({*override_seed_mm_, SeedOrigin::Configured});
      override_seed_mm_.reset();
      tracked_seed_mm_.reset();
    } else if (tracked_seed_mm_) {
      candidates.push_back({*tracked_seed_mm_, SeedOrigin::Tracked});
    }
  }
  if (config.seed_mm) candidates.push_back({*config.seed_mm, SeedOrigin::Configured});
  if (phantom_seed_mm_) candidates.push_back({*phantom_seed_mm_, SeedOrigin::Phantom});
  {
    const volume::Vec3f centre =
        input.index_to_mm((input.dims() - volume::Vec3i::Ones()).cast<float>() * 0.5f);
    candidates.push_back({{centre.x(), centre.y(), centre.z()}, SeedOrigin::Centre});
  }
  const Candidate* chosen = nullptr;
  nlohmann::json refused = nlohmann::json::array();
  for (const Candidate& c : candidates) {
    const auto why = check_seed(input, volume::Vec3f(c.mm[0], c.mm[1], c.mm[2]));
    if (!why) {
      chosen = &c;
      break;
    }
    refused.push_back({{"origin", to_string(c.origin)}, {"seed_mm", vec_json(c.mm)}, {"why", *why}});
  }
  nlohmann::json line = nlohmann::json::object();
  if (!refused.empty()) line["seeds_refused"] = refused;
  if (!chosen) {
    fail("no usable seed: " + refused.back()["why"].get<std::string>(), std::move(line));
    return;
  }
  const volume::Vec3f seed_mm(chosen->mm[0], chosen->mm[1], chosen->mm[2]);
  line["seed_mm"] = vec_json(chosen->mm);
  line["seed_origin"] = to_string(chosen->origin);
  stats_.set_seed(chosen->mm, to_string(chosen->origin));

  PipelineResult result;
  try {
    result = run_pipeline(input, seed_mm, config.pipeline, buffers_, abort_.get_token());
  } catch (const std::exception& e) {
    fail(std::string("pipeline: ") + e.what(), std::move(line));
    return;
  }
  nlohmann::json& timings = line["timings_ms"];
  timings["queue_wait"] = queue_wait_ms;
  for (const auto& [stage, ms] : result.timings.stages()) timings[stage] = ms;
  timings["total"] = result.timings.total_ms;
  if (!result.ok) {
    fail(abort_.stop_requested() ? "shutdown: aborted by a second signal" : result.error,
         std::move(line));
    return;
  }
  if (result.deepest_interior_mm) {
    const auto& d = *result.deepest_interior_mm;
    std::lock_guard lock(seed_mutex_);
    if (!override_seed_mm_) tracked_seed_mm_ = std::array<float, 3>{d.x(), d.y(), d.z()};
  }
  line["genus"] = result.topology.genus;
  line["components"] = result.topology.components;
  line["watertight"] = result.topology.watertight;
  line["vertices"] = result.topology.vertices;
  line["faces"] = result.topology.faces;
  line["volume_ml"] = result.enclosed_volume_ml;
  line["balloon_iterations"] = result.balloon_iterations;

  if (hooks_.result) hooks_.result(input, result.mesh, seed_mm, seq);  // web hook: /slices

  WriteJob job;
  job.sequence = seq;
  job.epoch = item.epoch;
  job.received = item.received;
  job.report = report_json(result, "sequence " + std::to_string(seq), input, seed_mm);
  job.report["sequence"] = seq;
  job.report["seed_origin"] = to_string(chosen->origin);
  job.report["queue_wait_ms"] = queue_wait_ms;
  job.mesh = std::move(result.mesh);
  job.timings = result.timings;
  job.line = std::move(line);
  write_queue_->push(std::move(job));
}

void LiveRunner::writer_loop() {
  while (auto job = write_queue_->pop()) {
    try {
      write_one(*job);
    } catch (const std::exception& e) {
      fail_fatal(e.what());
    }
  }
}

void LiveRunner::write_one(WriteJob& job) {
  const std::string stem = stem_of(job.sequence, job.epoch);
  const fs::path mesh_rel = fs::path("meshes") / (stem + ".ply");
  const fs::path report_rel = fs::path("reports") / (stem + ".json");
  const Clock::time_point write_started = Clock::now();
  Clock::time_point mesh_written;
  try {
    write_atomically(out_ / mesh_rel, [&](const fs::path& tmp) {
      if (auto err = reconstruct::write_ply(job.mesh, tmp)) throw std::runtime_error(err->message);
    });
    publish_copy_atomically(out_ / mesh_rel, out_ / "latest.ply");
    mesh_written = Clock::now();  // the latency ends here: the mesh is where readers look
    write_file_atomically(out_ / report_rel, job.report.dump(2) + "\n");
  } catch (const std::exception& e) {
    // An output that cannot be written is this volume's failure; the journal line still goes out.
    nlohmann::json line = std::move(job.line);
    line["reason"] = std::string("write: ") + e.what();
    journal_->write(job.sequence, JournalStatus::Failed, std::move(line), job.epoch);
    stats_.count(JournalStatus::Failed);
    stats_.set_last_error(e.what());
    spdlog::error("sequence {}: {}", job.sequence, e.what());
    return;
  }
  const Clock::time_point done = Clock::now();
  const double latency_ms = ms_between(job.received, mesh_written);
  nlohmann::json line = std::move(job.line);
  line["mesh"] = mesh_rel.string();
  line["report"] = report_rel.string();
  line["timings_ms"]["write"] = ms_between(write_started, done);
  line["latency_ms"] = latency_ms;
  const int genus = line.value("genus", -1);
  journal_->write(job.sequence, JournalStatus::Processed, std::move(line), job.epoch);
  stats_.count(JournalStatus::Processed);
  stats_.add_latency(latency_ms);
  stats_.set_last_processed(job.sequence, genus);
  for (const auto& [stage, ms] : job.timings.stages()) stats_.add_stage_time(stage, ms);
  spdlog::info("sequence {} processed: genus {}, {:.0f} ms after it arrived", job.sequence, genus,
               latency_ms);
  {
    std::lock_guard lock(written_mutex_);
    written_stems_.push_back(stem);
  }
  prune_outputs();
}

void LiveRunner::prune_outputs() {
  const std::uint64_t keep = config_snapshot().keep_meshes;
  if (keep == 0) return;
  std::lock_guard lock(written_mutex_);
  while (written_stems_.size() > keep) {
    std::error_code ec;
    fs::remove(out_ / "meshes" / (written_stems_.front() + ".ply"), ec);
    fs::remove(out_ / "reports" / (written_stems_.front() + ".json"), ec);
    written_stems_.erase(written_stems_.begin());
  }
}

}  // namespace sonomesh::daemon
