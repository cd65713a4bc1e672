// breathing_bench: a breathing phantom stream through the pipeline, one volume after another with
// reused buffers (as the daemon's worker runs it): per volume the reconstruction grid, the FFTW
// plans made for it, the reconstruct stage's time, genus and Dice against the truth.
//   breathing_bench [--phantom cyst-needle] [--size 128] [--spacing 0.4] [--volumes 40]
//                   [--rate 10] [--start 0] [--warm [--track [--chain 10]]] [--realism echo]
//                   [--contrast C] [--quiet]
// --warm: each volume's balloon starts inside the previous one's (daemon::WarmStart, 3 voxels in,
// as the daemon's worker with a still target) and the seed is the previous deepest point, as the
// daemon's worker runs it (issue 17). --track: the previous surface is tracked where it is safe.
// A breathing target should land on a handful of grid sizes, so plans stop being made after the
// first few volumes (issue 17).
#include <CLI/CLI.hpp>
#include <algorithm>
#include <cstdio>
#include <optional>
#include <set>
#include <string>
#include <tuple>
#include <vector>

#include "daemon/internal/metrics.h"
#include "daemon/pipeline.h"
#include "reconstruct/internal/fft_plans.h"
#include "sim/sim.h"

namespace {

using namespace sonomesh;

struct Args {
  std::string phantom = "cyst-needle";
  int size_vox = 128, volumes = 40;
  float spacing_mm = 0.4f, rate_hz = 10.0f, start_s = 0.0f;
  float contrast = -1.0f;          // < 0: the phantom's own
  std::string realism = "simple";  // echo: sim::with_echo_realism
  bool quiet = false, warm_start = false, track = false;
  int chain = daemon::PipelineConfig{}.track_max_chain;
};

// What the stream's volumes add up to.
struct Tally {
  std::set<std::tuple<int, int, int>> grids;
  std::vector<double> reconstruct_ms, total_ms, balloon_ms, labels_ms, start_mesh_ms, warm_total_ms,
      tracked_total_ms;
  double dice_min = 1.0, dice_sum = 0.0;
  int genus_wrong = 0, failed = 0, warm_count = 0;

  void add(const daemon::PipelineResult& r, const sim::Phantom& p, double dice) {
    dice_min = std::min(dice_min, dice);
    dice_sum += dice;
    genus_wrong += r.topology.genus != p.genus;
    grids.insert({r.grid_dims.x(), r.grid_dims.y(), r.grid_dims.z()});
    reconstruct_ms.push_back(r.timings.reconstruct_ms);
    total_ms.push_back(r.timings.total_ms);
    balloon_ms.push_back(r.timings.balloon_ms);
    labels_ms.push_back(r.timings.labels_ms);
    if (r.tracking.chain > 0) {
      tracked_total_ms.push_back(r.timings.total_ms);
    } else if (r.warm_start) {
      start_mesh_ms.push_back(r.balloon_stats.start_mesh_ms);
      warm_total_ms.push_back(r.timings.total_ms);
    }
  }
};

double pct(std::vector<double> v, double q) {
  if (v.empty()) return 0.0;
  std::sort(v.begin(), v.end());
  return v[std::min(v.size() - 1, std::size_t(q * double(v.size())))];
}

// Labels' voxels over the truth's, minus one.
double volume_error(const volume::Volume& labels, const volume::Volume& truth) {
  const auto count = [](const volume::Volume& v) {
    return static_cast<double>(
        std::count_if(v.u8().begin(), v.u8().end(), [](auto x) { return x; }));
  };
  return count(labels) / std::max(1.0, count(truth)) - 1.0;
}

void print_row(int i, const daemon::PipelineResult& r, std::size_t plans, double dice,
               double volume_error) {
  std::printf(
      "%4d %3dx%3dx%3d %7.3f %5zu %9.1f %8.1f %5d %6.4f %+6.2f%% %8.1f it %d vit %lld evolve "
      "%.0f remesh %.0f start %.1f %s | smooth %.1f open %.1f mesh %.1f refit %.1f labels %.1f\n",
      i, r.grid_dims.x(), r.grid_dims.y(), r.grid_dims.z(), r.grid_cell_mm, plans,
      r.timings.reconstruct_ms, r.timings.total_ms, r.topology.genus, dice, 100.0 * volume_error,
      r.timings.balloon_ms, r.balloon_iterations,
      static_cast<long long>(r.balloon_stats.vertex_iterations), r.balloon_stats.evolve_ms,
      r.balloon_stats.remesh_ms, r.balloon_stats.start_mesh_ms,
      r.tracking.chain ? "track"
      : r.warm_start   ? ("warm " + r.tracking.refused).c_str()
                       : r.start_reason.c_str(),
      r.timings.smooth_ms, r.timings.opening_ms, r.timings.mesh_ms, r.timings.reinflate_ms,
      r.timings.labels_ms);
}

void print_summary(const Args& a, const Tally& t, std::size_t plans) {
  const int ok = a.volumes - t.failed;
  std::printf(
      "%s %d³ x%d: grid sizes %zu, FFTW plans %zu, reconstruct p50 %.1f p90 %.1f ms, total p50 "
      "%.1f ms, genus wrong %d, Dice mean %.4f min %.4f, failed %d\n"
      "  warm starts %d of %d, balloon p50 %.1f ms, labels+deepest p50 %.1f ms\n"
      "  warm balloon volumes: start mesh min %.1f p50 %.1f p90 %.1f ms, total p50 %.1f ms\n"
      "  tracked volumes: %zu, total p50 %.1f p90 %.1f ms\n",
      a.phantom.c_str(), a.size_vox, a.volumes, t.grids.size(), plans, pct(t.reconstruct_ms, 0.5),
      pct(t.reconstruct_ms, 0.9), pct(t.total_ms, 0.5), t.genus_wrong,
      ok > 0 ? t.dice_sum / ok : 0.0, t.dice_min, t.failed, t.warm_count, a.volumes,
      pct(t.balloon_ms, 0.5), pct(t.labels_ms, 0.5), pct(t.start_mesh_ms, 0.0),
      pct(t.start_mesh_ms, 0.5), pct(t.start_mesh_ms, 0.9), pct(t.warm_total_ms, 0.5),
      t.tracked_total_ms.size(), pct(t.tracked_total_ms, 0.5), pct(t.tracked_total_ms, 0.9));
}

// The phantom at time `time_s` of the stream.
sim::PhantomSpec spec_at(const Args& a, float time_s) {
  sim::PhantomSpec spec{.phantom = a.phantom,
                        .size_vox = a.size_vox,
                        .spacing_mm = volume::Vec3f::Constant(a.spacing_mm),
                        .time_s = time_s};
  if (a.realism == "echo") spec = sim::with_echo_realism(spec);
  if (a.contrast >= 0.0f) spec.contrast = a.contrast;
  return spec;
}

// The stream, volume by volume, as the daemon's worker runs it: buffers reused and, with --warm,
// the previous balloon (3 voxels in, its genus checked) and deepest point carried forward.
Tally run_stream(const Args& a) {
  daemon::PipelineConfig config;
  config.track_max_chain = a.chain;
  daemon::PipelineBuffers buffers;
  Tally t;
  std::optional<daemon::WarmStart> warm;
  std::optional<volume::Vec3f> tracked_mm;
  for (int i = 0; i < a.volumes; ++i) {
    const sim::Phantom p = sim::make_phantom(spec_at(a, a.start_s + float(i) / a.rate_hz));
    const std::size_t plans0 = reconstruct::internal::fft_plan_stats().plans_created;
    const volume::Vec3f seed_mm = tracked_mm.value_or(p.seed_mm);
    const daemon::PipelineResult r =
        daemon::run_pipeline(p.image, seed_mm, config, buffers, warm ? &*warm : nullptr);
    warm.reset();
    // (A suspect result starts nothing, as the worker's seed policy has it.)
    if (a.warm_start && r.ok && r.quality_ok) {
      warm = daemon::warm_start_from(r, 3.0f * a.spacing_mm);
      if (!a.track) warm->previous.reset();
      tracked_mm = r.deepest_interior_mm;
    }
    t.warm_count += r.warm_start;
    if (!r.ok || !r.labels) {
      ++t.failed;
      std::printf("%4d failed: %s\n", i, r.error.c_str());
      continue;
    }
    const double dice = daemon::internal::dice(*r.labels, p.truth);
    t.add(r, p, dice);
    if (!a.quiet)
      print_row(i, r, reconstruct::internal::fft_plan_stats().plans_created - plans0, dice,
                volume_error(*r.labels, p.truth));
  }
  return t;
}

}  // namespace

int main(int argc, char** argv) {
  CLI::App app{"breathing_bench: grid sizes and FFTW plans over a breathing phantom stream"};
  Args a;
  app.add_option("--phantom", a.phantom);
  app.add_option("--size", a.size_vox)->check(CLI::Range(16, 512));
  app.add_option("--spacing", a.spacing_mm)->check(CLI::PositiveNumber);
  app.add_option("--volumes", a.volumes)->check(CLI::Range(1, 1000));
  app.add_option("--rate", a.rate_hz)->check(CLI::PositiveNumber);
  app.add_option("--start", a.start_s, "breathing time of the first volume, s")
      ->check(CLI::NonNegativeNumber);
  app.add_flag("--quiet", a.quiet, "summary only");
  app.add_option("--realism", a.realism, "simple or echo (sim::with_echo_realism)")
      ->check(CLI::IsMember({"simple", "echo"}));
  app.add_option("--contrast", a.contrast, "target contrast (default: the phantom's)");
  app.add_flag("--warm", a.warm_start, "warm start from the previous volume's balloon");
  app.add_flag("--track", a.track, "with --warm: track the previous surface where it is safe");
  app.add_option("--chain", a.chain, "with --track: volumes in a row tracked at most")
      ->check(CLI::Range(0, 1000));
  CLI11_PARSE(app, argc, argv);
  if (!a.quiet)
    std::printf("%4s %-12s %7s %5s %9s %8s %5s %6s %7s %10s\n", "vol", "grid", "cell_mm", "plans",
                "recon_ms", "total_ms", "genus", "dice", "vol_err", "balloon_ms");
  const std::size_t plans_before = reconstruct::internal::fft_plan_stats().plans_created;
  const Tally t = run_stream(a);
  print_summary(a, t, reconstruct::internal::fft_plan_stats().plans_created - plans_before);
  return t.failed == 0 ? 0 : 1;
}
