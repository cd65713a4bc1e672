// igtl_bench: what the OpenIGTLink output adds to a 128³ result, against the file path.
//
// Interleaved per volume: the files sink's write (meshes/N.ply, latest.ply, reports/N.json, each
// fsync'd: where the file path's latency ends) and the OpenIGTLink server's publish until a
// loopback client has the whole POLYDATA, then the whole set (POLYDATA, IMAGE, STRING). In the
// daemon the IGTL publish follows the journal line, so its added latency is publish -> POLYDATA.
//
//   igtl_bench [--count N] [--size N]
#include <unistd.h>

#include <algorithm>
#include <atomic>
#include <chrono>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <mutex>
#include <string>
#include <thread>
#include <vector>

#include "daemon/internal/file_sink.h"
#include "daemon/internal/igtl_messages.h"
#include "daemon/internal/igtl_server.h"
#include "igtl_test_client.h"
#include "reconstruct/reconstruct.h"

using namespace sonomesh;
using Clock = std::chrono::steady_clock;

namespace {

double ms(Clock::duration d) { return std::chrono::duration<double, std::milli>(d).count(); }

double quantile(std::vector<double> v, double q) {
  std::sort(v.begin(), v.end());
  return v[std::min(v.size() - 1, static_cast<std::size_t>(q * (v.size() - 1) + 0.5))];
}

daemon::ProcessedVolume ball(int n) {
  const volume::Vec3i dims(n, n, n);
  const volume::Vec3f spacing(0.4f, 0.4f, 0.4f), origin(0, 0, 0);
  volume::Volume field(dims, spacing, origin, volume::VoxelType::Float32);
  volume::Volume labels(dims, spacing, origin, volume::VoxelType::UInt8);
  const float c = 0.5f * (n - 1), r = 0.3f * n;
  for (int k = 0; k < n; ++k)
    for (int j = 0; j < n; ++j)
      for (int i = 0; i < n; ++i) {
        const std::size_t at = (static_cast<std::size_t>(k) * n + j) * n + i;
        const float d = std::sqrt((i - c) * (i - c) + (j - c) * (j - c) + (k - c) * (k - c)) - r;
        field.f32()[at] = d;
        labels.u8()[at] = d <= 0 ? 1 : 0;
      }
  daemon::ProcessedVolume v;
  v.mesh = reconstruct::marching_cubes(field, 0.0f);
  v.labels = std::move(labels);
  v.report = {{"bench", true}};
  return v;
}

}  // namespace

int main(int argc, char** argv) {
  int count = 40, size = 128;
  for (int i = 1; i + 1 < argc; i += 2) {
    if (!std::strcmp(argv[i], "--count")) count = std::atoi(argv[i + 1]);
    if (!std::strcmp(argv[i], "--size")) size = std::atoi(argv[i + 1]);
  }
  daemon::ProcessedVolume v = ball(size);
  std::printf("%d³ labels, mesh of %zu vertices / %zu triangles\n", size, v.mesh.vertices.size(),
              v.mesh.triangles.size());
  const std::filesystem::path out =
      std::filesystem::temp_directory_path() / ("igtl_bench_" + std::to_string(::getpid()));
  std::filesystem::create_directories(out / "meshes");
  std::filesystem::create_directories(out / "reports");
  daemon::RunConfig config;
  daemon::SharedConfig shared(config);
  daemon::FileSink files(out, shared);
  daemon::RunStats stats;
  daemon::IgtlServer server(stats);
  const int port = server.start({"127.0.0.1", 0});
  sonomesh::testing::TestClient client(port);

  std::vector<double> file_ms, mesh_ms, set_ms, pack_mesh_ms, pack_labels_ms;
  for (int s = 1; s <= count; ++s) {
    v.sequence = static_cast<std::uint64_t>(s);
    nlohmann::json line = {{"sequence", s}, {"status", "processed"}};
    const auto p0 = Clock::now();
    const std::string packed_mesh = daemon::pack_igtl_mesh(v.mesh, daemon::IgtlTime::now());
    const auto p1 = Clock::now();
    const std::string packed_labels = daemon::pack_igtl_labels(*v.labels, daemon::IgtlTime::now());
    pack_mesh_ms.push_back(ms(p1 - p0));
    pack_labels_ms.push_back(ms(Clock::now() - p1));
    const auto t0 = Clock::now();
    files.write(v, line);
    file_ms.push_back(ms(Clock::now() - t0));
    const auto t1 = Clock::now();
    server.on_line(line, &v);
    auto mesh = client.read();
    mesh_ms.push_back(ms(Clock::now() - t1));
    auto image = client.read();
    auto text = client.read();
    set_ms.push_back(ms(Clock::now() - t1));
    if (!mesh || !image || !text) {
      std::fprintf(stderr, "igtl_bench: the client did not get set %d\n", s);
      return 1;
    }
  }
  server.stop();
  std::filesystem::remove_all(out);
  std::printf("%-34s %8s %8s\n", "per volume (ms)", "p50", "p95");
  std::printf("%-34s %8.2f %8.2f\n", "files sink write (fsync'd)", quantile(file_ms, 0.5),
              quantile(file_ms, 0.95));
  std::printf("%-34s %8.2f %8.2f\n", "of which: pack POLYDATA", quantile(pack_mesh_ms, 0.5),
              quantile(pack_mesh_ms, 0.95));
  std::printf("%-34s %8.2f %8.2f\n", "of which: pack IMAGE", quantile(pack_labels_ms, 0.5),
              quantile(pack_labels_ms, 0.95));
  std::printf("%-34s %8.2f %8.2f\n", "igtl publish -> POLYDATA received", quantile(mesh_ms, 0.5),
              quantile(mesh_ms, 0.95));
  std::printf("%-34s %8.2f %8.2f\n", "igtl publish -> whole set received", quantile(set_ms, 0.5),
              quantile(set_ms, 0.95));
  return 0;
}
