// process_bench: per-stage time of the pipeline (daemon::run_pipeline, what `sonomeshd process`
// and every daemon job run) on simulator phantoms of 128³ and 256³.
//   process_bench [--sizes 128,256] [--phantoms cyst-needle,torus] [--repeat 5] [--format md|json]
//                 [--fresh-buffers] [--no-labels] [--no-coarse-start] [--finest-always]
//                 [--realism simple|echo] [--contrast 0.7]
//   process_bench --hash [--sizes 96,128] [--phantoms ...] [--threads 1,2]
// --hash prints, per case, a 64-bit FNV-1a hash of the balloon (positions and stop reasons) and of
// the final mesh (positions and triangles) instead of timings: a refactoring must keep them.
// One warm-up run per case (FFTW plans, page faults), then the median of --repeat runs per stage.
// The runs reuse one PipelineBuffers, as the daemon's worker does; --fresh-buffers allocates the
// smoothed volume anew per run, as a single `sonomeshd process` does. --no-labels skips the label
// volume (the daemon without an OpenIGTLink listener, `process` without --labels): `labels` is
// then the deepest-point search alone. --no-coarse-start runs the plain cold start (the sphere at
// full resolution) instead of the coarse-to-fine one; the `c2f` column is the coarse-to-fine
// start's downsampling + coarse pass + fine pass (ms, medians), "-" when it was not used.
// --finest-always runs the full-resolution pass after the coarse one even where the coarse
// balloon could stand for it (PipelineConfig::coarse_start_finest_when_needed off).
// --realism echo makes the phantoms with sim::with_echo_realism at --contrast.
// Targets (DESIGN/issue 4): total <= 100 ms at 128³, <= 750 ms at 256³.
#include <CLI/CLI.hpp>
#include <algorithm>
#include <cstdint>
#include <cstdio>
#include <nlohmann/json.hpp>
#include <string>
#include <vector>

#include "daemon/pipeline.h"
#include "sim/sim.h"

namespace {

using namespace sonomesh;

// FNV-1a over raw bytes: positions are compared bit for bit, not within a tolerance.
struct Fnv1a {
  std::uint64_t h = 1469598103934665603ull;
  void add(const void* data, std::size_t bytes) {
    const auto* p = static_cast<const unsigned char*>(data);
    for (std::size_t i = 0; i < bytes; ++i) h = (h ^ p[i]) * 1099511628211ull;
  }
  template <class T>
  void add_all(const std::vector<T>& v) {
    if (!v.empty()) add(v.data(), v.size() * sizeof(T));
  }
};

int print_hashes(const std::vector<int>& sizes, const std::vector<std::string>& phantoms,
                 const std::vector<int>& threads, bool coarse_start) {
  std::printf("%-12s %5s %7s %-18s %-18s %s\n", "phantom", "size", "threads", "balloon", "mesh",
              "genus");
  for (const int size : sizes)
    for (const std::string& name : phantoms)
      for (const int t : threads) {
        const sim::Phantom phantom = sim::make_phantom({.phantom = name, .size_vox = size});
        daemon::PipelineConfig config;
        config.balloon.threads = t;
        config.poisson.fft_threads = t;
        config.coarse_start = coarse_start;
        const daemon::PipelineResult r =
            daemon::run_pipeline(phantom.image, phantom.seed_mm, config);
        Fnv1a balloon, mesh;
        balloon.add_all(r.balloon.vertices);
        balloon.add_all(r.balloon_stop);
        mesh.add_all(r.mesh.vertices);
        mesh.add_all(r.mesh.triangles);
        std::printf("%-12s %5d %7d %016llx   %016llx   %d%s\n", name.c_str(), size, t,
                    static_cast<unsigned long long>(balloon.h),
                    static_cast<unsigned long long>(mesh.h), r.topology.genus,
                    r.ok ? "" : " (failed)");
        std::fflush(stdout);
      }
  return 0;
}

double median(std::vector<double> values) {
  std::sort(values.begin(), values.end());
  return values[values.size() / 2];
}

}  // namespace

struct BenchSettings {
  int repeat = 5;
  bool fresh_buffers = false, want_labels = true, coarse_start = true, finest_always = false;
  std::string realism = "simple";
  float contrast = 0.7f;
  std::string format = "md";
};

sim::Phantom bench_phantom(const std::string& name, int size, const BenchSettings& settings) {
  sim::PhantomSpec spec{.phantom = name, .size_vox = size};
  if (settings.realism == "echo") spec = sim::with_echo_realism(spec);
  spec.contrast = settings.contrast;
  return sim::make_phantom(spec);
}

// One phantom at one size: `repeat` timed runs after a warm-up, their medians printed as a row.
void bench_case(const std::string& name, int size, const BenchSettings& settings) {
  const sim::Phantom phantom = bench_phantom(name, size, settings);
  daemon::PipelineConfig config;
  config.want_labels = settings.want_labels;
  config.coarse_start = settings.coarse_start;
  config.coarse_start_finest_when_needed = !settings.finest_always;
  const int repeat = settings.repeat;
  const std::string& format = settings.format;
  daemon::PipelineBuffers buffers;
  auto run = [&] {
    if (settings.fresh_buffers) buffers = daemon::PipelineBuffers{};
    return daemon::run_pipeline(phantom.image, phantom.seed_mm, config, buffers);
  };
  daemon::PipelineResult result = run();
  std::vector<double> smooth, balloon, opening, reconstruct, mesh, reinflate, resurface, labels,
      total;
  std::vector<double> downsample, coarse, fine;
  for (int r = 0; r < repeat; ++r) {
    result = run();
    const daemon::StageTimings& t = result.timings;
    downsample.push_back(result.coarse_start.downsample_ms);
    coarse.push_back(result.coarse_start.coarse_ms);
    fine.push_back(result.coarse_start.fine_ms);
    smooth.push_back(t.smooth_ms);
    balloon.push_back(t.balloon_ms);
    opening.push_back(t.opening_ms);
    reconstruct.push_back(t.reconstruct_ms);
    mesh.push_back(t.mesh_ms);
    reinflate.push_back(t.reinflate_ms);
    resurface.push_back(t.resurface_ms);
    labels.push_back(t.labels_ms);
    total.push_back(t.total_ms);
  }
  const double target_ms = size <= 128 ? 100.0 : 750.0;
  const std::string grid = std::to_string(result.grid_dims.x()) + "x" +
                           std::to_string(result.grid_dims.y()) + "x" +
                           std::to_string(result.grid_dims.z());
  char c2f[64] = "-";
  if (result.coarse_start.used)
    std::snprintf(c2f, sizeof c2f, "%.1f+%.1f+%.1f", median(downsample), median(coarse),
                  median(fine));
  if (format == "json") {
    nlohmann::json row = {{"phantom", name},
                          {"size", size},
                          {"ok", result.ok},
                          {"smooth_ms", median(smooth)},
                          {"balloon_ms", median(balloon)},
                          {"opening_ms", median(opening)},
                          {"reconstruct_ms", median(reconstruct)},
                          {"mesh_ms", median(mesh)},
                          {"reinflate_ms", median(reinflate)},
                          {"resurface_ms", median(resurface)},
                          {"labels_ms", median(labels)},
                          {"total_ms", median(total)},
                          {"target_ms", target_ms},
                          {"iterations", result.balloon_iterations},
                          {"grid", grid},
                          {"coarse_start", result.coarse_start.used},
                          {"downsample_ms", median(downsample)},
                          {"coarse_ms", median(coarse)},
                          {"fine_ms", median(fine)}};
    std::printf("%s\n", row.dump().c_str());
  } else {
    std::printf(
        "| %s%s | %d³ | %.1f | %.1f | %.1f | %.1f | %.1f | %.1f | %.1f | %.1f | %.1f | %s %.0f "
        "| %d | %s | %s |\n",
        name.c_str(), result.ok ? "" : " (failed)", size, median(smooth), median(balloon),
        median(opening), median(reconstruct), median(mesh), median(reinflate), median(resurface),
        median(labels), median(total), median(total) <= target_ms ? "≤" : "> (missed)", target_ms,
        result.balloon_iterations, grid.c_str(), c2f);
  }
}

int main(int argc, char** argv) {
  CLI::App app{"process_bench: per-stage pipeline time"};
  std::vector<int> sizes{128, 256};
  std::vector<std::string> phantoms{"sphere", "cyst-needle"};
  BenchSettings settings;
  bool hash = false, no_labels = false, no_coarse_start = false;
  std::vector<int> threads{1, 2};
  app.add_option("--sizes", sizes, "Volume edges (voxels)")->delimiter(',');
  app.add_option("--phantoms", phantoms, "Phantom names")->delimiter(',');
  app.add_option("--repeat", settings.repeat, "Timed runs per case")->check(CLI::Range(1, 100));
  app.add_option("--format", settings.format, "md or json")->check(CLI::IsMember({"md", "json"}));
  app.add_flag("--fresh-buffers", settings.fresh_buffers, "Allocate the smoothing buffers per run");
  app.add_flag("--no-labels", no_labels, "Skip the label volume (the deepest point only)");
  app.add_flag("--no-coarse-start", no_coarse_start, "The plain cold start at full resolution");
  app.add_flag("--finest-always", settings.finest_always,
               "The full-resolution pass after every coarse one");
  app.add_option("--realism", settings.realism, "Image model")
      ->check(CLI::IsMember({"simple", "echo"}));
  app.add_option("--contrast", settings.contrast, "Target contrast")->check(CLI::Range(0.0, 1.0));
  app.add_flag("--hash", hash, "Print balloon and mesh hashes instead of timings");
  app.add_option("--threads", threads, "Thread counts for --hash")->delimiter(',');
  try {
    app.parse(argc, argv);
  } catch (const CLI::CallForHelp& e) {
    return app.exit(e);
  } catch (const CLI::ParseError& e) {
    std::fprintf(stderr, "process_bench: %s\n", e.what());
    return 2;
  }
  settings.want_labels = !no_labels;
  settings.coarse_start = !no_coarse_start;
  if (hash) {
    try {
      return print_hashes(sizes, phantoms, threads, settings.coarse_start);
    } catch (const std::exception& e) {
      std::fprintf(stderr, "process_bench: %s\n", e.what());
      return 1;
    }
  }
  if (settings.format == "md") {
    std::printf(
        "| phantom | size | smooth | balloon | opening | reconstruct | mesh | reinflate "
        "| resurface | labels | total (ms) | target | balloon iterations | grid | c2f |\n");
    std::printf("|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|\n");
  }
  try {
    for (const int size : sizes)
      for (const std::string& name : phantoms) {
        bench_case(name, size, settings);
        std::fflush(stdout);
      }
  } catch (const std::exception& e) {
    std::fprintf(stderr, "process_bench: %s\n", e.what());
    return 1;
  }
  return 0;
}
