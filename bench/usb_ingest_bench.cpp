// Sustained ingest over the emulated USB probe: the real libusb path of the usb: source (async
// bulk IN, protocol parsing, CRC checks) fed with simulated 128^3 volumes by a umockdev probe.
// Reports volumes/s and MB/s. Re-executes itself under libumockdev-preload like the hil tests.
//
//   usb_ingest_bench [--seconds S] [--size N] [--uint16]
#include <unistd.h>

#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <string>
#include <vector>

#include "acquire/acquire.h"
#include "acquire/protocol.h"
#include "sim/sim.h"
#include "tests/hil/fake_usb_probe.h"

namespace {

using namespace sonomesh;
using Clock = std::chrono::steady_clock;

int run(double seconds, int size, bool uint16) {
  // Distinct simulated volumes (breathing phantom); the probe cycles through them, patching the
  // sequence into the header so the host sees a gap-free stream of fresh records.
  constexpr int kDistinct = 8;
  std::vector<std::vector<std::uint8_t>> records;
  for (int i = 0; i < kDistinct; ++i) {
    sim::PhantomSpec spec;
    spec.size_vox = size;
    spec.seed = 7;
    spec.time_s = 0.1f * static_cast<float>(i);
    acquire::RawVolume raw = sim::to_raw(sim::make_phantom(spec).image, 0, 0);
    if (uint16) {
      std::vector<std::uint8_t> wide(raw.voxels.size() * 2);
      for (std::size_t k = 0; k < raw.voxels.size(); ++k) {
        const std::uint16_t v = static_cast<std::uint16_t>(raw.voxels[k] * 257u);
        std::memcpy(&wide[2 * k], &v, 2);
      }
      raw.voxels = std::move(wide);
      raw.type = acquire::ProbeVoxelType::UInt16;
    }
    auto rec = acquire::encode_volume_record(raw);
    if (!rec) {
      std::fprintf(stderr, "encode: %s\n", acquire::to_string(rec.error()).c_str());
      return 1;
    }
    records.push_back(std::move(*rec));
  }
  const std::size_t record_bytes = records.front().size();

  hil::FakeUsbBus bus;
  hil::FakeUsbProbe& probe = bus.add_probe({});
  std::uint64_t next_sequence = 0;
  probe.set_producer([&](std::vector<std::uint8_t>& out) {
    const auto& tmpl = records[next_sequence % kDistinct];
    acquire::RecordHeader header = acquire::decode_header(tmpl.data());
    header.sequence = next_sequence;
    header.timestamp_ns = next_sequence * 33'000'000ull;
    const auto head = acquire::encode_header(header);
    out.assign(tmpl.begin(), tmpl.end());
    std::memcpy(out.data(), head.data(), head.size());
    ++next_sequence;
  });

  auto source = acquire::open_source("usb:1209:0001");
  if (!source) {
    std::fprintf(stderr, "open: %s\n", acquire::to_string(source.error()).c_str());
    return 1;
  }
  // Warm up (first transfers, allocations), then measure.
  for (int i = 0; i < 5; ++i) {
    auto r = (*source)->next(std::chrono::seconds(5));
    if (!r) {
      std::fprintf(stderr, "warm-up: %s\n", acquire::to_string(r.error()).c_str());
      return 1;
    }
  }
  std::uint64_t volumes = 0, errors = 0, voxel_bytes = 0;
  std::uint64_t last_seq = 0;
  bool ordered = true;
  const auto t0 = Clock::now();
  const std::clock_t c0 = std::clock();
  while (std::chrono::duration<double>(Clock::now() - t0).count() < seconds) {
    auto r = (*source)->next(std::chrono::seconds(5));
    if (!r) {
      ++errors;
      std::fprintf(stderr, "error: %s\n", acquire::to_string(r.error()).c_str());
      if (errors > 10) return 1;
      continue;
    }
    if (volumes > 0 && r->sequence != last_seq + 1) ordered = false;
    last_seq = r->sequence;
    voxel_bytes += r->voxels.size();
    ++volumes;
  }
  const double wall = std::chrono::duration<double>(Clock::now() - t0).count();
  const double cpu = static_cast<double>(std::clock() - c0) / CLOCKS_PER_SEC;
  std::printf(
      "usb_ingest_bench: %d^3 %s volumes over emulated USB (libusb async bulk IN, 4 x 1 MiB)\n",
      size, uint16 ? "uint16" : "uint8");
  std::printf("  volumes        %llu in %.2f s\n", static_cast<unsigned long long>(volumes), wall);
  std::printf("  rate           %.1f volumes/s (target >= 30)\n",
              static_cast<double>(volumes) / wall);
  std::printf("  throughput     %.1f MB/s of records (%.2f MB each), %.1f MB/s voxels\n",
              static_cast<double>(volumes) * static_cast<double>(record_bytes) / wall / 1e6,
              static_cast<double>(record_bytes) / 1e6,
              static_cast<double>(voxel_bytes) / wall / 1e6);
  std::printf("  process cpu    %.2f s (%.0f%% of one core, host and emulated device together)\n",
              cpu, 100.0 * cpu / wall);
  // On a shared machine the rate is bounded by the CPU share the process gets (every URB is a
  // round trip between the host thread and umockdev's thread); the CPU cost per volume says what
  // an unloaded core could sustain.
  if (volumes > 0 && cpu > 0)
    std::printf("  cpu per volume %.2f ms (=> %.0f volumes/s per fully available core)\n",
                1000.0 * cpu / static_cast<double>(volumes), static_cast<double>(volumes) / cpu);
  std::printf("  errors         %llu, sequences %s\n", static_cast<unsigned long long>(errors),
              ordered ? "consecutive" : "NOT consecutive");
  return errors == 0 && ordered ? 0 : 1;
}

}  // namespace

int main(int argc, char** argv) {
  const char* preload = std::getenv("LD_PRELOAD");
  if (!preload || !std::strstr(preload, "libumockdev-preload")) {
    std::string value = "libumockdev-preload.so.0";
    if (preload && *preload) value = std::string(preload) + ":" + value;
    setenv("LD_PRELOAD", value.c_str(), 1);
    execv("/proc/self/exe", argv);
    std::perror("execv(/proc/self/exe)");
    return 127;
  }
  double seconds = 3.0;
  int size = 128;
  bool uint16 = false;
  for (int i = 1; i < argc; ++i) {
    const std::string a = argv[i];
    if (a == "--seconds" && i + 1 < argc)
      seconds = std::atof(argv[++i]);
    else if (a == "--size" && i + 1 < argc)
      size = std::atoi(argv[++i]);
    else if (a == "--uint16")
      uint16 = true;
    else {
      std::fprintf(stderr, "usage: usb_ingest_bench [--seconds S] [--size N] [--uint16]\n");
      return 2;
    }
  }
  if (seconds <= 0 || size < 16 || size > 512) {
    std::fprintf(stderr, "usb_ingest_bench: --seconds must be > 0 and --size in 16..512\n");
    return 2;
  }
  return run(seconds, size, uint16);
}
