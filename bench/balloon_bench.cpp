// balloon_bench: speed and accuracy of the balloon (segment::inflate_balloon) on speckled
// phantoms. Target: <= 60 ms per 128^3 volume on 2 cores (smoothing excluded: the pipeline
// computes it once per volume for every stage).
//
//   balloon_bench [--size N] [--repeat R] [--threads T] [--seed N] [--max-iterations N]
//                 [--fraction F] [--max-area A] [--plain-cost] [--dot-rise] [--noise-allowance]
//                 [--no-snap]
//                 [phantom ...]
//
// Prints per phantom: balloon time (median and fastest of R runs: on a shared machine the fastest
// is the steadier figure), iterations, vertex count, stop counts, τ_cost, the time per phase, and
// the distance of the balloon's Boundary-stopped vertices to the voxelised true wall.
#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <stdexcept>
#include <string>
#include <vector>

#include "segment/segment.h"
#include "sim/sim.h"

using namespace sonomesh;
using volume::Vec3f;
using volume::Vec3i;

namespace {

// Distance from p to the voxelised truth wall by a local search (labels differ across a face).
float wall_distance_vox(const volume::Volume& truth, const Vec3f& p_mm, int reach = 4) {
  const Vec3f u = truth.mm_to_index(p_mm);
  const Vec3i c(static_cast<int>(std::lround(u.x())), static_cast<int>(std::lround(u.y())),
                static_cast<int>(std::lround(u.z())));
  const Vec3i d = truth.dims();
  const auto& t = truth.u8();
  float best = 1e9f;
  for (int k = c.z() - reach; k <= c.z() + reach; ++k)
    for (int j = c.y() - reach; j <= c.y() + reach; ++j)
      for (int i = c.x() - reach; i <= c.x() + reach; ++i) {
        if (i < 0 || j < 0 || k < 0 || i + 1 >= d.x() || j + 1 >= d.y() || k + 1 >= d.z()) continue;
        const bool in = t[truth.linear_index(i, j, k)] != 0;
        const Vec3i nb[3] = {{i + 1, j, k}, {i, j + 1, k}, {i, j, k + 1}};
        for (const auto& n : nb)
          if ((t[truth.linear_index(n.x(), n.y(), n.z())] != 0) != in) {
            const Vec3f m = 0.5f * (Vec3f(i, j, k) + n.cast<float>());
            best = std::min(best, (m - u).norm());
          }
      }
  return best;
}

}  // namespace

struct Args {
  int size = 128, repeat = 5, phantom_seed = 11;
  // The library's defaults unless a flag says otherwise: the bench measures what the daemon runs.
  segment::BalloonOptions options;
  std::vector<std::string> names;
};

// The command line into `args`; false (after one line on stderr) for an unknown option.
bool parse_args(int argc, char** argv, Args& args) {
  auto& o = args.options;
  for (int i = 1; i < argc; ++i) {
    const std::string a = argv[i];
    const bool value = i + 1 < argc;
    if (a == "--size" && value)
      args.size = std::atoi(argv[++i]);
    else if (a == "--repeat" && value)
      args.repeat = std::atoi(argv[++i]);
    else if (a == "--threads" && value)
      o.threads = std::atoi(argv[++i]);
    else if (a == "--seed" && value)
      args.phantom_seed = std::atoi(argv[++i]);
    else if (a == "--max-iterations" && value)
      o.max_iterations = std::atoi(argv[++i]);
    else if (a == "--noise-allowance" || a == "--no-noise-allowance")
      o.noise_allowance = a == "--noise-allowance";
    else if (a == "--plain-cost")
      o.relative_cost = false;
    else if (a == "--dot-rise")
      o.rise_per_axis = false;
    else if (a == "--no-snap")
      o.snap_to_wall = false;
    else if (a == "--max-area" && value)
      o.max_area_fraction = static_cast<float>(std::atof(argv[++i]));
    else if (a == "--fraction" && value)
      o.tau_cost_fraction = static_cast<float>(std::atof(argv[++i]));
    else if (a.rfind("--", 0) == 0) {
      std::fprintf(stderr,
                   "balloon_bench: unknown option '%s' (see the usage at the top of "
                   "bench/balloon_bench.cpp)\n",
                   a.c_str());
      return false;
    } else
      args.names.push_back(a);
  }
  if (args.names.empty()) args.names = {"sphere", "torus", "cyst-needle"};
  return true;
}

// Where the Boundary-stopped vertices lie against the voxelised truth wall.
struct WallStats {
  double mean_vox = 0;
  float p95_vox = 0, max_vox = 0;
  double inside_percent = 0;  // of all vertices, inside the truth
  long beyond_reach = 0;      // Boundary vertices with no wall within wall_distance_vox's reach
};

WallStats wall_stats(const sim::Phantom& ph, const segment::BalloonResult& r) {
  std::vector<float> dist;
  int inside = 0;
  for (std::size_t i = 0; i < r.mesh.vertices.size(); ++i) {
    const Vec3f u = ph.truth.mm_to_index(r.mesh.vertices[i]);
    const Vec3i c(static_cast<int>(std::lround(u.x())), static_cast<int>(std::lround(u.y())),
                  static_cast<int>(std::lround(u.z())));
    if (ph.truth.contains_index(c) && ph.truth.u8()[ph.truth.linear_index(c.x(), c.y(), c.z())])
      ++inside;
    if (r.stop[i] == segment::StopReason::Boundary)
      dist.push_back(wall_distance_vox(ph.truth, r.mesh.vertices[i]));
  }
  std::sort(dist.begin(), dist.end());
  // No wall within reach (in the needle, far in tissue, or at the volume's edge): counted apart
  // so that they do not swamp the statistics.
  const auto beyond = std::find_if(dist.begin(), dist.end(), [](float x) { return x > 1e8f; });
  WallStats w;
  w.beyond_reach = dist.end() - beyond;
  dist.erase(beyond, dist.end());
  for (float x : dist) w.mean_vox += x;
  w.mean_vox /= std::max<std::size_t>(1, dist.size());
  w.p95_vox = dist.empty() ? 0.0f : dist[dist.size() * 95 / 100];
  w.max_vox = dist.empty() ? 0.0f : dist.back();
  w.inside_percent = 100.0 * inside / std::max<std::size_t>(1, r.mesh.vertices.size());
  return w;
}

// BALLOON_BENCH_VERBOSE: the vertices that stopped badly (iteration limit, curvature, or on the
// boundary cost more than a voxel from the wall).
void print_bad_stops(const sim::Phantom& ph, const segment::BalloonResult& r) {
  for (std::size_t i = 0; i < r.mesh.vertices.size(); ++i) {
    const float wall = wall_distance_vox(ph.truth, r.mesh.vertices[i]);
    if (r.stop[i] == segment::StopReason::IterationLimit ||
        r.stop[i] == segment::StopReason::Curvature ||
        (r.stop[i] == segment::StopReason::Boundary && wall > 1.0f)) {
      const Vec3f u = ph.truth.mm_to_index(r.mesh.vertices[i]);
      std::printf("    v%zu stop %d at ijk (%.1f %.1f %.1f) wall %.2f vox\n", i,
                  static_cast<int>(r.stop[i]), u.x(), u.y(), u.z(), wall);
    }
  }
}

void print_result(const std::string& name, int size, const std::vector<double>& sorted_ms,
                  const sim::Phantom& ph, const segment::BalloonResult& r) {
  const WallStats w = wall_stats(ph, r);
  const auto& s = r.stats.stop_counts;
  char stops[64];
  std::snprintf(stops, sizeof stops, "%d/%d/%d/%d/%d", s[0], s[1], s[2], s[3], s[4]);
  std::printf("%-12s %5d %6.1f/%6.1f %6d %6zu  %-28s %7.2f  %.2f/%.2f/%.2f, %.1f%%, %ld\n",
              name.c_str(), size, sorted_ms[sorted_ms.size() / 2], sorted_ms.front(),
              r.stats.iterations, r.mesh.vertices.size(), stops, r.stats.tau_cost_used, w.mean_vox,
              w.p95_vox, w.max_vox, w.inside_percent, w.beyond_reach);
  std::printf(
      "    seed level %.1f sigma %.1f tissue %.1f rho %.2f/mm r0 %.2f mm, remesh %d (splits %d, "
      "collapses %d)%s%s\n",
      r.stats.seed_level, r.stats.seed_sigma, r.stats.tissue_level, r.stats.noise_rise_per_mm,
      r.stats.initial_radius_mm, r.stats.remesh_passes, r.stats.splits, r.stats.collapses,
      r.stats.stalled ? ", stalled" : "", r.converged ? ", converged" : "");
  std::printf(
      "    phases (last run) ms: evolve %.1f, normals %.1f, mark A_t %.1f, remesh %.1f; %lld "
      "vertex-iterations\n",
      r.stats.evolve_ms, r.stats.normals_ms, r.stats.mark_ms, r.stats.remesh_ms,
      static_cast<long long>(r.stats.vertex_iterations));
  // A_t's sparse grid against a dense one of 4 bytes per voxel (what it replaced).
  std::printf("    A_t: %zu voxels swept, %.2f MB (dense: %.2f MB)\n", r.stats.front_voxels,
              static_cast<double>(r.stats.front_grid_bytes) / 1e6,
              4.0 * static_cast<double>(ph.image.voxel_count()) / 1e6);
}

int run(int argc, char** argv) {
  Args args;
  if (!parse_args(argc, argv, args)) return 2;
  std::printf("%-12s %5s %13s %6s %6s  %-28s %7s  %s\n", "phantom", "size", "ms med/min", "iters",
              "verts", "stops mov/bnd/crv/self/lim", "tau",
              "wall dist vox (bnd) mean/p95/max, inside-truth %, bnd beyond 4 vox");
  for (const auto& name : args.names) {
    const auto ph = sim::make_phantom({.phantom = name,
                                       .size_vox = args.size,
                                       .seed = static_cast<std::uint32_t>(args.phantom_seed)});
    const float vox = ph.image.spacing_mm().minCoeff();
    const auto smoothed = volume::smooth_gaussian(ph.image, vox);
    std::vector<double> ms;
    segment::BalloonResult r;
    for (int k = 0; k < args.repeat; ++k) {
      const auto t0 = std::chrono::steady_clock::now();
      r = segment::inflate_balloon(smoothed, ph.seed_mm, args.options);
      ms.push_back(
          std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count());
    }
    std::sort(ms.begin(), ms.end());
    if (!r.error.empty()) {
      std::printf("%-12s %5d  error: %s (r0 %.2f mm, %d iterations, %.0f ms)\n", name.c_str(),
                  args.size, r.error.c_str(), r.stats.initial_radius_mm, r.stats.iterations,
                  ms[ms.size() / 2]);
      continue;
    }
    if (std::getenv("BALLOON_BENCH_VERBOSE")) print_bad_stops(ph, r);
    print_result(name, args.size, ms, ph, r);
  }
  return 0;
}

// Bad input (an unknown phantom, a size out of range) reaches here as the simulator's or the
// balloon's exception: one line and exit 2, not a terminate.
int main(int argc, char** argv) {
  try {
    return run(argc, argv);
  } catch (const std::exception& e) {
    std::fprintf(stderr, "balloon_bench: %s\n", e.what());
    return 2;
  }
}
