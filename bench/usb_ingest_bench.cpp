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

// Distinct simulated volumes (breathing phantom) encoded as probe records; empty on failure.
std::vector<std::vector<std::uint8_t>> make_records(int size, bool uint16, int count) {
  std::vector<std::vector<std::uint8_t>> records;
  for (int i = 0; i < count; ++i) {
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
      return {};
    }
    records.push_back(std::move(*rec));
  }
  return records;
}

struct Ingest {
  std::uint64_t volumes = 0, errors = 0, voxel_bytes = 0;
  bool ordered = true;
  double wall_s = 0, cpu_s = 0;
};

// Reads from `source` for `seconds`; false after more than 10 errors.
bool ingest(acquire::Source& source, double seconds, Ingest& in) {
  std::uint64_t last_seq = 0;
  const auto t0 = Clock::now();
  const std::clock_t c0 = std::clock();
  while (std::chrono::duration<double>(Clock::now() - t0).count() < seconds) {
    auto r = source.next(std::chrono::seconds(5));
    if (!r) {
      ++in.errors;
      std::fprintf(stderr, "error: %s\n", acquire::to_string(r.error()).c_str());
      if (in.errors > 10) return false;
      continue;
    }
    if (in.volumes > 0 && r->sequence != last_seq + 1) in.ordered = false;
    last_seq = r->sequence;
    in.voxel_bytes += r->voxels.size();
    ++in.volumes;
  }
  in.wall_s = std::chrono::duration<double>(Clock::now() - t0).count();
  in.cpu_s = static_cast<double>(std::clock() - c0) / CLOCKS_PER_SEC;
  return true;
}

void report(const Ingest& in, int size, bool uint16, std::size_t record_bytes) {
  const double volumes = static_cast<double>(in.volumes), wall = in.wall_s, cpu = in.cpu_s;
  std::printf(
      "usb_ingest_bench: %d^3 %s volumes over emulated USB (libusb async bulk IN, 4 x 1 MiB)\n",
      size, uint16 ? "uint16" : "uint8");
  std::printf("  volumes        %llu in %.2f s\n", static_cast<unsigned long long>(in.volumes),
              wall);
  std::printf("  rate           %.1f volumes/s (target >= 30)\n", volumes / wall);
  std::printf("  throughput     %.1f MB/s of records (%.2f MB each), %.1f MB/s voxels\n",
              volumes * static_cast<double>(record_bytes) / wall / 1e6,
              static_cast<double>(record_bytes) / 1e6,
              static_cast<double>(in.voxel_bytes) / wall / 1e6);
  std::printf("  process cpu    %.2f s (%.0f%% of one core, host and emulated device together)\n",
              cpu, 100.0 * cpu / wall);
  // On a shared machine the rate is bounded by the CPU share the process gets (every URB is a
  // round trip between the host thread and umockdev's thread); the CPU cost per volume says what
  // an unloaded core could sustain.
  if (in.volumes > 0 && cpu > 0)
    std::printf("  cpu per volume %.2f ms (=> %.0f volumes/s per fully available core)\n",
                1000.0 * cpu / volumes, volumes / cpu);
  std::printf("  errors         %llu, sequences %s\n", static_cast<unsigned long long>(in.errors),
              in.ordered ? "consecutive" : "NOT consecutive");
}

int run(double seconds, int size, bool uint16) {
  // The probe cycles through the records, patching the sequence into the header so that the host
  // sees a gap-free stream of fresh records.
  constexpr int kDistinct = 8;
  const auto records = make_records(size, uint16, kDistinct);
  if (records.empty()) return 1;
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
  for (int i = 0; i < 5; ++i) {  // warm up (first transfers, allocations), then measure
    auto r = (*source)->next(std::chrono::seconds(5));
    if (!r) {
      std::fprintf(stderr, "warm-up: %s\n", acquire::to_string(r.error()).c_str());
      return 1;
    }
  }
  Ingest in;
  if (!ingest(**source, seconds, in)) return 1;
  report(in, size, uint16, records.front().size());
  return in.errors == 0 && in.ordered ? 0 : 1;
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
