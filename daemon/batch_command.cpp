// `sonomeshd batch --manifest FILE.jsonl --out DIR [--jobs N] [--index I]`: every manifest line
// through the pipeline in one process (buffers and FFT plans reused across inputs), results in
// DIR/ID.ply, DIR/ID.json and one line per input in DIR/results.jsonl. Idempotent: an input
// whose line exists is skipped, so a killed run resumes where it stopped.
#include <signal.h>
#include <unistd.h>

#include <atomic>
#include <chrono>
#include <cstdio>
#include <memory>
#include <mutex>
#include <string>
#include <thread>
#include <vector>

#include "daemon/commands.h"
#include "daemon/internal/batch_manifest.h"
#include "daemon/internal/clock.h"
#include "daemon/internal/outputs.h"
#include "daemon/pipeline.h"

namespace sonomesh::daemon {
namespace {

namespace fs = std::filesystem;
using internal::Clock;
using internal::ms_since;

// Exit codes: 0 every selected line has a result, 1 results could not be written or the run was
// interrupted, 2 bad arguments or manifest.
constexpr int kFailed = 1;
constexpr int kBadArguments = 2;

std::atomic<bool> g_interrupted{false};
extern "C" void on_interrupt(int) { g_interrupted = true; }

struct BatchArgs {
  std::string manifest, out;
  int jobs = 1;
  long long index = -1;
  bool quiet = false;
};

// One input through the pipeline; its results.jsonl line (status processed or failed).
nlohmann::json run_item(const BatchItem& item, const fs::path& out, PipelineBuffers& buffers) {
  const Clock::time_point started = Clock::now();
  nlohmann::json line = {{"index", item.index}, {"id", item.id}, {"input", item.input.string()}};
  auto failed = [&](const std::string& reason) {
    line["status"] = "failed";
    line["reason"] = reason;
    line["elapsed_ms"] = ms_since(started);
    return line;
  };
  auto read = volume::read_volume(item.input.string());
  if (!read) return failed(read.error->message);
  const volume::Volume& input = read.volume;
  Vec3f seed_mm;
  if (item.seed_index) {
    const Vec3i ijk((*item.seed_index)[0], (*item.seed_index)[1], (*item.seed_index)[2]);
    if (!input.contains_index(ijk)) return failed("seed_index is outside the volume");
    seed_mm = input.index_to_mm(ijk.cast<float>());
  } else {
    // seed_mm is in the world frame (LPS mm); the pipeline runs in the grid frame.
    seed_mm = internal::seed_world_to_grid_mm(
        input, Vec3f((*item.seed_mm)[0], (*item.seed_mm)[1], (*item.seed_mm)[2]));
  }
  const Vec3f seed_world_mm = input.grid_to_world_mm(seed_mm);
  line["seed_mm"] = {seed_world_mm.x(), seed_world_mm.y(), seed_world_mm.z()};
  if (auto problem = check_seed(input, seed_mm, item.target.value_or(TargetPolarity::Dark)))
    return failed(*problem);

  PipelineConfig config;
  if (item.target) config.target = *item.target;
  config.want_labels = false;  // batch writes mesh and report only
  config.track_max_chain = 0;  // files are independent: nothing to track
  PipelineResult result;
  try {
    result = run_pipeline(input, seed_mm, config, buffers);
  } catch (const std::exception& e) {
    return failed(std::string("pipeline: ") + e.what());
  }
  const nlohmann::json report = report_json(result, item.input.string(), input, seed_mm);
  const fs::path report_path = out / (item.id + ".json");
  if (auto problem = internal::write_text_atomically(report_path, report.dump(2) + "\n")) {
    return failed(*problem);
  }
  line["report"] = report_path.filename().string();
  if (!result.ok) return failed(result.error);
  const fs::path mesh_path = out / (item.id + ".ply");
  if (auto problem = internal::write_mesh_ply(result.mesh, input, mesh_path))
    return failed(*problem);
  line["status"] = "processed";
  line["mesh"] = mesh_path.filename().string();
  line["genus"] = result.topology.genus;
  line["components"] = result.topology.components;
  line["watertight"] = result.topology.watertight;
  line["volume_ml"] = result.enclosed_volume_ml;
  line["target"] = to_string(result.target);
  line["quality"] = result.quality_ok ? "ok" : "suspect";
  if (!result.quality_ok) line["quality_reasons"] = result.quality_reasons;
  line["pipeline_ms"] = result.timings.total_ms;
  line["elapsed_ms"] = ms_since(started);
  return line;
}

// A progress bar on a terminal, one line per input otherwise (logs, Slurm output files).
class Progress {
 public:
  Progress(std::size_t total, bool quiet) : total_(total), quiet_(quiet), tty_(::isatty(2)) {}
  void done(const nlohmann::json& line) {
    std::lock_guard lock(mutex_);
    ++done_;
    if (line.value("status", "") == "failed") ++failed_;
    if (quiet_) return;
    if (!tty_) {
      std::fprintf(stderr, "batch: %zu/%zu %s %s%s\n", done_, total_, line.value("id", "").c_str(),
                   line.value("status", "").c_str(),
                   line.contains("reason") ? (": " + line.value("reason", "")).c_str() : "");
      return;
    }
    constexpr int kWidth = 30;
    const int filled = static_cast<int>(kWidth * done_ / std::max<std::size_t>(1, total_));
    const double per_item_s =
        std::chrono::duration<double>(Clock::now() - started_).count() / static_cast<double>(done_);
    std::fprintf(stderr, "\r[%s%s] %zu/%zu, %zu failed, ETA %.0f s ",
                 std::string(filled, '#').c_str(), std::string(kWidth - filled, '.').c_str(), done_,
                 total_, failed_, per_item_s * static_cast<double>(total_ - done_));
    if (done_ == total_) std::fprintf(stderr, "\n");
  }

 private:
  std::mutex mutex_;
  std::size_t total_, done_ = 0, failed_ = 0;
  bool quiet_, tty_;
  Clock::time_point started_ = Clock::now();
};

int run_batch(const BatchArgs& args) {
  std::string error;
  const auto items = read_manifest(args.manifest, error);
  if (!items) return std::fprintf(stderr, "sonomeshd batch: %s\n", error.c_str()), kBadArguments;
  if (args.index >= static_cast<long long>(items->size())) {
    std::fprintf(stderr, "sonomeshd batch: --index %lld: the manifest has %zu entries (0-%zu)\n",
                 args.index, items->size(), items->size() - 1);
    return kBadArguments;
  }
  const fs::path out = args.out;
  std::error_code ec;
  fs::create_directories(out, ec);
  if (ec) {
    std::fprintf(stderr, "sonomeshd batch: cannot create %s: %s\n", out.c_str(),
                 ec.message().c_str());
    return kFailed;
  }
  // Temporaries a killed run left (hidden .ID.tmp-PID.* names) are not removed here: another
  // process may be writing one right now (parallel --index runs share DIR).
  ResultsFile results(out / "results.jsonl");
  const std::set<std::string> done = results.done_ids();
  std::vector<const BatchItem*> todo;
  for (const BatchItem& item : *items) {
    if (args.index >= 0 && item.index != static_cast<std::size_t>(args.index)) continue;
    if (!done.count(item.id)) todo.push_back(&item);
  }
  const std::size_t selected = args.index >= 0 ? 1 : items->size();
  if (!args.quiet) {
    std::fprintf(stderr,
                 "sonomeshd batch: %zu input(s), %zu already done, %zu to run on %d job(s)\n",
                 selected, selected - todo.size(), todo.size(), args.jobs);
  }
  ::signal(SIGINT, on_interrupt);
  ::signal(SIGTERM, on_interrupt);
  Progress progress(todo.size(), args.quiet);
  std::atomic<std::size_t> next{0};
  std::atomic<bool> write_failed{false};
  auto worker = [&] {
    PipelineBuffers buffers;  // reused across this worker's inputs
    for (std::size_t i; !g_interrupted && !write_failed && (i = next++) < todo.size();) {
      const nlohmann::json line = run_item(*todo[i], out, buffers);
      try {
        results.append(line, /*unless_done=*/args.index >= 0);
      } catch (const std::exception& e) {
        std::fprintf(stderr, "sonomeshd batch: %s\n", e.what());
        write_failed = true;
        return;
      }
      progress.done(line);
    }
  };
  std::vector<std::thread> threads;
  for (int j = 1; j < args.jobs; ++j) threads.emplace_back(worker);
  worker();
  for (auto& t : threads) t.join();
  if (write_failed) return kFailed;
  if (g_interrupted) {
    std::fprintf(stderr, "sonomeshd batch: interrupted; run it again to resume\n");
    return kFailed;
  }
  return 0;
}

}  // namespace

void add_batch_command(CLI::App& app, int& exit_code) {
  auto args = std::make_shared<BatchArgs>();
  CLI::App* cmd = app.add_subcommand(
      "batch", "Segment every volume of a manifest: DIR/ID.ply, DIR/ID.json, DIR/results.jsonl");
  cmd->add_option("--manifest", args->manifest,
                  "JSON lines: {\"input\": PATH, \"seed_mm\": [x,y,z] | \"seed_index\": [i,j,k], "
                  "\"id\"?, \"target\"?}")
      ->required();
  cmd->add_option("--out", args->out, "Output directory")->required();
  cmd->add_option("--jobs", args->jobs, "Inputs processed at once in this process")
      ->check(CLI::Range(1, 64));
  cmd->add_option("--index", args->index,
                  "Run only entry I (0-based; Slurm: $SLURM_ARRAY_TASK_ID, Kubernetes: "
                  "$JOB_COMPLETION_INDEX)")
      ->check(CLI::NonNegativeNumber);
  cmd->add_flag("--quiet", args->quiet, "No progress output");
  cmd->callback([args, &exit_code] {
    try {
      exit_code = run_batch(*args);
    } catch (const std::exception& e) {
      std::fprintf(stderr, "sonomeshd batch: %s\n", e.what());
      exit_code = kFailed;
    }
  });
}

}  // namespace sonomesh::daemon
