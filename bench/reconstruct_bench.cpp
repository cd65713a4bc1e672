// Speed and accuracy of the second step on analytic samples sized like real targets:
// ~60 voxels across in a 128³ volume (FFT grid ~80³) and ~120 voxels in a 256³ volume (~160³).
// Targets (DESIGN / issue 4): reconstruction <= 30 ms and marching cubes <= 10 ms at 128³.
// Prints a table; never run by ctest.

#include <Eigen/Geometry>
#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <ctime>
#include <functional>
#include <string>
#include <vector>

#include "reconstruct/internal/fft_plans.h"
#include "reconstruct/reconstruct.h"

using namespace sonomesh;
using reconstruct::PointCloud;
using reconstruct::Vec3f;

namespace {

constexpr float kPi = 3.14159265358979f;

PointCloud sphere(float R, float spacing_mm) {
  const int n = int(4 * kPi * R * R / (spacing_mm * spacing_mm));
  PointCloud pc;
  const float golden = kPi * (3.0f - std::sqrt(5.0f));
  for (int i = 0; i < n; ++i) {
    const float z = 1.0f - 2.0f * (i + 0.5f) / n, r = std::sqrt(1.0f - z * z);
    const Vec3f d(r * std::cos(golden * i), r * std::sin(golden * i), z);
    pc.points.push_back(R * d);
    pc.normals.push_back(d);
    pc.area_mm2.push_back(4 * kPi * R * R / n);
  }
  return pc;
}

PointCloud torus(float R, float r, float spacing_mm) {
  const int nu = int(2 * kPi * R / spacing_mm), nv = int(2 * kPi * r / spacing_mm);
  PointCloud pc;
  for (int i = 0; i < nu; ++i)
    for (int j = 0; j < nv; ++j) {
      const float u = 2 * kPi * (i + 0.5f) / nu, v = 2 * kPi * (j + 0.5f) / nv;
      const Vec3f n(std::cos(v) * std::cos(u), std::cos(v) * std::sin(u), std::sin(v));
      pc.points.push_back(Vec3f(R * std::cos(u), R * std::sin(u), 0) + r * n);
      pc.normals.push_back(n);
      pc.area_mm2.push_back((R + r * std::cos(v)) * r * (2 * kPi / nu) * (2 * kPi / nv));
    }
  return pc;
}

double cpu_ms() {
  timespec ts{};
  clock_gettime(CLOCK_PROCESS_CPUTIME_ID, &ts);
  return ts.tv_sec * 1e3 + ts.tv_nsec * 1e-6;
}

// Median wall time; *cpu gets the median process CPU time (all threads), which stays meaningful
// when other jobs share the two cores and inflate the wall clock.
double median_ms(int runs, const std::function<void()>& fn, double* cpu = nullptr) {
  std::vector<double> t, c;
  for (int i = 0; i < runs; ++i) {
    const double c0 = cpu_ms();
    const auto a = std::chrono::steady_clock::now();
    fn();
    t.push_back(
        std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - a).count());
    c.push_back(cpu_ms() - c0);
  }
  std::sort(t.begin(), t.end());
  std::sort(c.begin(), c.end());
  if (cpu) *cpu = c[c.size() / 2];
  return t[t.size() / 2];
}

struct Case {
  std::string name;
  PointCloud samples;
  float cell_mm;
  std::function<float(const Vec3f&)> distance;  // to the true surface, mm
  int genus;
  Vec3f seed_mm;  // inside the solid
};

void run(const Case& c, reconstruct::DivergenceMode mode, int threads, bool measure) {
  reconstruct::PoissonOptions o{.cell_mm = c.cell_mm,
                                .fft_threads = threads,
                                .divergence = mode,
                                .measure_fft_plans = measure};
  const auto first = std::chrono::steady_clock::now();
  reconstruct::IndicatorGrid g = reconstruct::poisson_indicator(c.samples, o);  // plans made here
  const double first_ms =
      std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - first).count();
  double rec_cpu = 0.0, mc_cpu = 0.0;
  const double rec_ms = median_ms(
      9, [&] { g = reconstruct::poisson_indicator(c.samples, o); }, &rec_cpu);
  reconstruct::Mesh m;
  const double mc_ms = median_ms(
      9, [&] { m = reconstruct::marching_cubes(g.chi, g.iso); }, &mc_cpu);
  reconstruct::Mesh kept;
  const double sel_ms =
      median_ms(5, [&] { kept = reconstruct::component_enclosing(m, c.seed_mm); });
  const auto topo = reconstruct::analyze_topology(kept);
  double err = 0.0;
  for (const auto& v : kept.vertices) err += c.distance(v);
  err /= std::max<std::size_t>(1, kept.vertices.size());
  std::printf(
      "%-10s %-7s %dT %-4s grid %3dx%3dx%3d  samples %6zu  first %7.1f ms  reconstruct %6.1f ms "
      "(cpu %6.1f)  "
      "mc %5.1f ms (cpu %5.1f)  select %5.1f ms  tris %6d  genus %d%s  watertight %d manifold %d  "
      "mean err %.3f cell\n",
      c.name.c_str(), mode == reconstruct::DivergenceMode::Spectral ? "spectral" : "central",
      threads, measure ? "meas" : "est", g.chi.dims().x(), g.chi.dims().y(), g.chi.dims().z(),
      c.samples.points.size(), first_ms, rec_ms, rec_cpu, mc_ms, mc_cpu, sel_ms, topo.faces,
      topo.genus, topo.genus == c.genus ? "" : " (WRONG)", topo.watertight, topo.manifold,
      err / g.cell_mm);
}

}  // namespace

int main() {
  // 128³ volume at 0.5 mm: a 60-voxel target is 30 mm across; the balloon's edges are ~1.5 voxels.
  std::vector<Case> cases;
  cases.push_back({"sphere128", sphere(15.0f, 0.75f), 0.5f,
                   [](const Vec3f& p) { return std::abs(p.norm() - 15.0f); }, 0, Vec3f::Zero()});
  cases.push_back({"torus128", torus(10.5f, 4.5f, 0.75f), 0.5f,
                   [](const Vec3f& p) {
                     return std::abs(std::hypot(std::hypot(p.x(), p.y()) - 10.5f, p.z()) - 4.5f);
                   },
                   1, Vec3f(10.5f, 0, 0)});
  cases.push_back({"sphere256", sphere(30.0f, 0.75f), 0.5f,
                   [](const Vec3f& p) { return std::abs(p.norm() - 30.0f); }, 0, Vec3f::Zero()});
  for (const auto& c : cases)
    for (auto mode :
         {reconstruct::DivergenceMode::Spectral, reconstruct::DivergenceMode::CentralDifference})
      for (int threads : {1, 2}) run(c, mode, threads, false);
  for (const auto& c : cases) run(c, reconstruct::DivergenceMode::Spectral, 2, true);
  const auto stats = reconstruct::internal::fft_plan_stats();
  std::printf("FFTW plans created %zu, cache hits %zu\n", stats.plans_created, stats.cache_hits);

  // Label rasterisation of the 128³ result onto a 128³ grid.
  reconstruct::PoissonOptions o{.cell_mm = 0.5f};
  const auto r = reconstruct::reconstruct_surface(cases[0].samples, Vec3f::Zero(), o);
  const volume::Volume like(volume::Vec3i(128, 128, 128), Vec3f::Constant(0.5f),
                            Vec3f::Constant(-32.0f), volume::VoxelType::UInt8);
  const double lab_ms = median_ms(5, [&] { reconstruct::rasterize_labels(r.mesh, like); });
  std::printf(
      "rasterize_labels 128^3: %.1f ms; reconstruct_surface: reconstruct %.1f ms, mesh %.1f ms\n",
      lab_ms, r.reconstruct_ms, r.mesh_ms);
  return 0;
}
