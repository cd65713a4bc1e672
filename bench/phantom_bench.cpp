// Phantom generation speed: the daemon's `sim:` source generates volumes live (up to 10/s at
// 128^3), so make_phantom must stay well under 100 ms there once the speckle field is cached.
// Prints wall time and process CPU time (both cores), median of several runs.
#include <sys/resource.h>

#include <algorithm>
#include <chrono>
#include <cstdio>
#include <vector>

#include "sim/sim.h"

namespace {

double cpu_ms() {
  rusage u{};
  getrusage(RUSAGE_SELF, &u);
  return (u.ru_utime.tv_sec + u.ru_stime.tv_sec) * 1e3 +
         (u.ru_utime.tv_usec + u.ru_stime.tv_usec) * 1e-3;
}

double median(std::vector<double> v) {
  std::sort(v.begin(), v.end());
  return v[v.size() / 2];
}

}  // namespace

int main() {
  using namespace sonomesh::sim;
  std::printf("%-13s %5s %16s %16s %16s\n", "phantom", "size", "new seed wall ms", "cached wall ms",
              "cached cpu ms");
  std::uint32_t seed = 1000;
  for (int size : {64, 128, 256}) {
    for (const auto& name : phantom_names()) {
      const int runs = size >= 256 ? 3 : 7;
      std::vector<double> fresh, cached, cpu;
      for (int r = 0; r < runs; ++r) {
        PhantomSpec spec;
        spec.phantom = name;
        spec.size_vox = size;
        spec.seed = ++seed;  // new speckle field
        auto t0 = std::chrono::steady_clock::now();
        (void)make_phantom(spec);
        auto t1 = std::chrono::steady_clock::now();
        spec.time_s = 0.1f * static_cast<float>(r + 1);  // same seed, moved target: the live case
        const double c0 = cpu_ms();
        (void)make_phantom(spec);
        const double c1 = cpu_ms();
        auto t2 = std::chrono::steady_clock::now();
        fresh.push_back(std::chrono::duration<double, std::milli>(t1 - t0).count());
        cached.push_back(std::chrono::duration<double, std::milli>(t2 - t1).count());
        cpu.push_back(c1 - c0);
      }
      std::printf("%-13s %5d %16.1f %16.1f %16.1f\n", name.c_str(), size, median(fresh),
                  median(cached), median(cpu));
    }
  }
}
