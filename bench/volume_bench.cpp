// Speed of the volume hot paths: smoothing (target <= 5 ms at 128^3), gradient, trilinear sampling.
#include <benchmark/benchmark.h>

#include <random>

#include "volume/volume.h"

using namespace sonomesh::volume;

namespace {

Volume noise(int n, VoxelType type) {
  Volume v(Vec3i(n, n, n), Vec3f(1, 1, 1), Vec3f(0, 0, 0), type);
  std::mt19937 rng(1);
  for (std::size_t i = 0; i < v.voxel_count(); ++i) {
    const auto x = static_cast<std::uint8_t>(rng());
    if (type == VoxelType::UInt8)
      v.u8()[i] = x;
    else if (type == VoxelType::UInt16)
      v.u16()[i] = x;
    else
      v.f32()[i] = x;
  }
  return v;
}

// args: size, sigma in tenths of a mm, voxel type, reuse output buffer
void BM_SmoothGaussian(benchmark::State& state) {
  const Volume v = noise(static_cast<int>(state.range(0)), static_cast<VoxelType>(state.range(2)));
  const float sigma_mm = static_cast<float>(state.range(1)) / 10.0f;
  Volume s;
  for (auto _ : state) {
    if (state.range(3) == 0) {
      Volume fresh = smooth_gaussian(v, sigma_mm);
      benchmark::DoNotOptimize(fresh.f32().data());
    } else {
      smooth_gaussian(v, sigma_mm, s);  // steady state of a pipeline: output buffer reused
      benchmark::DoNotOptimize(s.f32().data());
    }
  }
  state.SetItemsProcessed(state.iterations() * static_cast<int64_t>(v.voxel_count()));
}
BENCHMARK(BM_SmoothGaussian)
    ->ArgsProduct({{128, 256}, {10, 20}, {0, 2}, {0, 1}})
    ->ArgNames({"n", "sigma_x10", "type", "reuse"})
    ->Unit(benchmark::kMillisecond)
    ->MeasureProcessCPUTime()  // CPU column = all threads; real time is what the target is about
    ->UseRealTime();

// A tracked volume's smoothing: a centred box of `edge_pct` % of each edge, against the whole
// (edge_pct 100), output reused. args: size, edge_pct; sigma 1 voxel, UInt8.
void BM_SmoothGaussianBox(benchmark::State& state) {
  const int n = static_cast<int>(state.range(0));
  const Volume v = noise(n, VoxelType::UInt8);
  const int edge = n * static_cast<int>(state.range(1)) / 100, lo = (n - edge) / 2;
  Volume s;
  smooth_gaussian(v, 1.0f, s);
  for (auto _ : state) {
    smooth_gaussian(v, 1.0f, Vec3i::Constant(lo), Vec3i::Constant(lo + edge), s);
    benchmark::DoNotOptimize(s.f32().data());
  }
}
BENCHMARK(BM_SmoothGaussianBox)
    ->ArgsProduct({{128}, {50, 65, 80, 100}})
    ->ArgNames({"n", "edge_pct"})
    ->Unit(benchmark::kMillisecond)
    ->MeasureProcessCPUTime()
    ->UseRealTime();

void BM_CentralGradient(benchmark::State& state) {
  const Volume v = noise(static_cast<int>(state.range(0)), VoxelType::Float32);
  Gradient g;
  for (auto _ : state) {
    central_gradient(v, g);
    benchmark::DoNotOptimize(g.gx.f32().data());
  }
}
BENCHMARK(BM_CentralGradient)
    ->Arg(128)
    ->Unit(benchmark::kMillisecond)
    ->MeasureProcessCPUTime()
    ->UseRealTime();

void BM_SampleGradient(benchmark::State& state) {
  const Volume v = noise(128, VoxelType::Float32);
  const Gradient g = central_gradient(v);
  std::mt19937 rng(2);
  std::uniform_real_distribution<float> u(0.0f, 127.0f);
  std::vector<Vec3f> pts(4096);
  for (auto& p : pts) p = Vec3f(u(rng), u(rng), u(rng));
  for (auto _ : state) {
    Vec3f acc = Vec3f::Zero();
    float s = 0.0f;
    for (const auto& p : pts) {
      acc += sample_gradient_mm(g, p);
      s += sample_mm(v, p);
    }
    benchmark::DoNotOptimize(acc);
    benchmark::DoNotOptimize(s);
  }
  state.SetItemsProcessed(state.iterations() * static_cast<int64_t>(pts.size()));
}
BENCHMARK(BM_SampleGradient);

}  // namespace

BENCHMARK_MAIN();
