#include "daemon/internal/live_runner.h"

#include <spdlog/spdlog.h>
#include <unistd.h>

#include <algorithm>
#include <thread>
#include <vector>

#include "daemon/internal/atomic_file.h"
#include "daemon/internal/file_sink.h"

namespace sonomesh::daemon {

namespace fs = std::filesystem;

namespace {

// Results waiting for the writer. Small: if the disk stalls, the worker waits rather than piling
// up meshes in memory.
constexpr std::size_t kResultQueueCapacity = 4;

void prepare_output_directory(const fs::path& out) {
  std::error_code ec;
  int stale = 0;
  for (const fs::path& dir : {out, out / "meshes", out / "reports"}) {
    fs::create_directories(dir, ec);
    if (ec) throw std::runtime_error("cannot create " + dir.string() + ": " + ec.message());
    stale += remove_stale_temporaries(dir);
  }
  if (stale > 0) spdlog::warn("removed {} temporary file(s) left by an earlier run", stale);
}

}  // namespace

LiveRunner::LiveRunner(RunConfig config, std::unique_ptr<acquire::Source> source,
                       SourceFactory factory, bool live,
                       std::optional<std::array<float, 3>> phantom_seed_mm)
    : config_(config), live_(live), out_(config.out) {
  prepare_output_directory(out_);
  events_ = std::make_unique<EventLog>(out_ / "events.jsonl");
  recorder_ = std::make_unique<Recorder>(out_ / "journal.jsonl", stats_);
  recorder_->add_sink(std::make_shared<FileSink>(out_, config_));
  // What a killed earlier run had in hand (received, no line yet) a live probe will not send
  // again; replay sends it again and it is processed then.
  if (live_) {
    for (const auto& [first, count] : recorder_->journal().holes_before()) {
      recorder_->record_lost(first, count, "in hand when an earlier run stopped");
    }
  }
  queue_ = std::make_unique<VolumeQueue>(config.queue_capacity,
                                         live_ ? QueueMode::KeepNewest : QueueMode::Block);
  results_ = std::make_unique<ResultQueue>(kResultQueueCapacity, QueueMode::Block);
  stats_.set_source(config.source, live_);
  stats_.set_queue_depth(0, config.queue_capacity);
  stats_.set_source_state(source ? SourceState::Connected : SourceState::Connecting);
  if (config.seed_mm) {
    stats_.set_seed(config.seed_mm, to_string(SeedOrigin::Configured));
  } else if (phantom_seed_mm) {
    stats_.set_seed(phantom_seed_mm, to_string(SeedOrigin::Phantom));
  } else {
    stats_.set_seed(std::nullopt, to_string(SeedOrigin::Centre));
  }
  acquisition_ = std::make_unique<Acquisition>(context(), std::move(source), std::move(factory),
                                               *queue_, live_);
  worker_ =
      std::make_unique<Worker>(context(), *queue_, *results_, phantom_seed_mm, abort_.get_token());
  writer_ = std::make_unique<Writer>(context(), *results_);
}

LiveRunner::~LiveRunner() = default;

RunContext LiveRunner::context() {
  return RunContext{config_, *recorder_, stats_, *events_,
                    [this](const std::string& what) { fail_fatal(what); }};
}

void LiveRunner::add_sink(std::shared_ptr<OutputSink> sink) {
  recorder_->add_sink(std::move(sink));
}

void LiveRunner::set_worker_turn_hook(std::function<void()> hook) {
  worker_->set_turn_hook(std::move(hook));
}

void LiveRunner::event(const std::string& kind, nlohmann::json fields) {
  events_->event(kind, std::move(fields));
}

void LiveRunner::fail_fatal(const std::string& what) {
  spdlog::critical("{}; stopping", what);
  stats_.set_last_error(what);
  fatal_ = true;
  request_stop();
}

void LiveRunner::request_stop() {
  if (stopping_.exchange(true)) abort_.request_stop();  // second request: the volume in hand too
  acquisition_->stop();
  // Wakes a replay push() blocked on a full queue; what was queued is journaled as skipped.
  for (const QueuedVolume& item : queue_->abort()) {
    RunContext c = context();
    record_skipped(c, item, "shutdown");
  }
}

void LiveRunner::reload(const RunConfig& next) {
  const RunConfig previous = config_.snapshot();
  RunConfig applied = next;
  bool restart_needed = false;
  auto keep = [&](auto& value, const auto& running) {
    if (!(value == running)) restart_needed = true;
    value = running;
  };
  keep(applied.source, previous.source);
  keep(applied.out, previous.out);
  keep(applied.http_address, previous.http_address);
  keep(applied.record_path, previous.record_path);
  keep(applied.igtl_listen, previous.igtl_listen);
  keep(applied.lanes, previous.lanes);
  // The labels follow the running OpenIGTLink server (run_command.cpp), not the file's.
  applied.pipeline.want_labels = previous.pipeline.want_labels;
  if (restart_needed) {
    spdlog::warn(
        "config reload: source, out, http, igtl_listen, record_path and lanes changes need "
        "a restart; keeping the running ones");
  }
  config_.update([&](RunConfig& c) { c = applied; });
  queue_->set_capacity(applied.queue_capacity);
  stats_.set_queue_depth(queue_->size(), applied.queue_capacity);
  if (applied.seed_mm && applied.seed_mm != previous.seed_mm)
    worker_->override_seed(*applied.seed_mm);
  spdlog::set_level(spdlog::level::from_str(applied.log_level));
  spdlog::info("configuration reloaded; applies from the next volume");
  event("config_reloaded");
}

std::optional<std::string> LiveRunner::set_seed(const std::array<float, 3>& seed_mm) {
  worker_->override_seed(seed_mm);
  config_.update([&](RunConfig& c) { c.seed_mm = seed_mm; });  // also the fallback from now on
  stats_.set_seed(seed_mm, to_string(SeedOrigin::Configured));
  spdlog::info("seed set to ({:.2f}, {:.2f}, {:.2f}) mm; used from the next volume", seed_mm[0],
               seed_mm[1], seed_mm[2]);
  event("seed_set", {{"seed_mm", {seed_mm[0], seed_mm[1], seed_mm[2]}}});
  return std::nullopt;
}

int LiveRunner::run() {
  const RunConfig config = config_.snapshot();
  // By default a live stream gets a lane per core (two at most): it drops what one lane cannot
  // keep up with. A replay keeps one, so each volume warm-starts from the one before it.
  const int cores = std::clamp(static_cast<int>(std::thread::hardware_concurrency()), 1, 2);
  const int lanes = config.lanes > 0 ? static_cast<int>(config.lanes) : live_ ? cores : 1;
  event("started", {{"source", config.source},
                    {"live", live_},
                    {"queue_capacity", config.queue_capacity},
                    {"lanes", lanes},
                    {"pid", static_cast<long long>(::getpid())}});
  if (auto described = acquisition_->describe_source()) {
    event("source_opened", {{"source", *described}});
  }
  std::thread writer([this] { writer_->run(); });
  std::vector<std::thread> workers;
  for (int lane = 0; lane < lanes; ++lane)
    workers.emplace_back([this, lane, lanes] { worker_->run(lane, lanes); });
  acquisition_->run();                      // on the calling thread
  for (std::thread& w : workers) w.join();  // each returns when the input queue is drained
  results_->close();
  writer.join();
  acquisition_->close_source();
  for (const auto& sink : recorder_->sinks()) sink->stop();
  const nlohmann::json counts = stats_.status_json()["volumes"];
  spdlog::info("stopped: {}", counts.dump());
  event("stopped", {{"volumes", counts}, {"reason", stopping_ ? "signal" : "end of stream"}});
  return fatal_ ? 1 : 0;
}

}  // namespace sonomesh::daemon
