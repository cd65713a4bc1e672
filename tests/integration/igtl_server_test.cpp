// The OpenIGTLink server against a test client written here (plain socket, headers parsed by
// hand from the protocol description, not through libOpenIGTLink).
#include "daemon/internal/igtl_server.h"

#include <arpa/inet.h>
#include <gtest/gtest.h>
#include <netinet/in.h>
#include <poll.h>
#include <sys/socket.h>
#include <unistd.h>

#include <chrono>
#include <cmath>
#include <cstring>
#include <nlohmann/json.hpp>
#include <optional>
#include <string>
#include <thread>
#include <vector>

#include "igtl_test_client.h"

using namespace sonomesh::daemon;
using namespace sonomesh::testing;
using namespace std::chrono_literals;
using sonomesh::volume::Volume;
using sonomesh::volume::VoxelType;

namespace {

// A labelled ball in an oblique, anisotropic grid, and a surface around it in world (LPS) mm.
ProcessedVolume oblique_ball(std::uint64_t sequence) {
  const Vec3i dims(32, 28, 24);
  const Vec3f spacing(0.5f, 0.6f, 0.7f), origin(10.0f, -20.0f, 5.0f);
  Volume labels(dims, spacing, origin, VoxelType::UInt8);
  const float a = 0.5f;  // 30 degrees about z, then the result tilted about x
  Mat3f rz, rx;
  rz << std::cos(a), -std::sin(a), 0, std::sin(a), std::cos(a), 0, 0, 0, 1;
  rx << 1, 0, 0, 0, std::cos(a), -std::sin(a), 0, std::sin(a), std::cos(a);
  labels.set_direction(rx * rz);
  const Vec3f centre_grid = origin + spacing.cwiseProduct(Vec3f(16, 14, 12));
  const float radius_mm = 5.0f;
  auto& v = labels.u8();
  for (int k = 0; k < dims.z(); ++k)
    for (int j = 0; j < dims.y(); ++j)
      for (int i = 0; i < dims.x(); ++i) {
        const Vec3f p = origin + spacing.cwiseProduct(Vec3f(i, j, k));
        v[(static_cast<std::size_t>(k) * dims.y() + j) * dims.x() + i] =
            (p - centre_grid).norm() <= radius_mm ? 1 : 0;
      }
  ProcessedVolume out;
  out.sequence = sequence;
  const int rings = 8, segments = 12;
  for (int r = 0; r <= rings; ++r) {
    for (int s = 0; s < segments; ++s) {
      const float th = 3.14159265f * r / rings, ph = 6.2831853f * s / segments;
      const Vec3f g = centre_grid + radius_mm * Vec3f(std::sin(th) * std::cos(ph),
                                                      std::sin(th) * std::sin(ph), std::cos(th));
      out.mesh.vertices.push_back(labels.grid_to_world_mm(g));
    }
  }
  for (int r = 0; r < rings; ++r)
    for (int s = 0; s < segments; ++s) {
      const std::uint32_t a0 = r * segments + s, a1 = r * segments + (s + 1) % segments;
      out.mesh.triangles.push_back({a0, a1, a0 + segments});
      out.mesh.triangles.push_back({a1, a1 + segments, a0 + segments});
    }
  out.labels = std::move(labels);
  return out;
}

nlohmann::json status_line(std::uint64_t sequence) {
  return {{"sequence", sequence}, {"status", "processed"}, {"quality", "ok"}, {"genus", 0}};
}

}  // namespace

TEST(IgtlServer, SendsMeshLabelsAndStatusInOneFrame) {
  RunStats stats;
  IgtlServer server(stats);
  const int port = server.start({"127.0.0.1", 0});
  TestClient client(port);
  ASSERT_TRUE(client.connected());
  std::this_thread::sleep_for(100ms);  // accepted before the result exists: no latest yet
  const ProcessedVolume v = oblique_ball(7);
  server.on_line(status_line(7), &v);
  server.on_line({{"sequence", 8}, {"status", "skipped"}}, nullptr);  // nothing is sent for it
  auto set = read_set(client);
  ASSERT_TRUE(set);
  EXPECT_EQ(set->points_ras.size(), v.mesh.vertices.size());
  EXPECT_EQ(set->polygons, v.mesh.triangles.size());
  // RAS is LPS with x and y negated.
  EXPECT_NEAR(set->points_ras[5].x(), -v.mesh.vertices[5].x(), 1e-4);
  EXPECT_NEAR(set->points_ras[5].z(), v.mesh.vertices[5].z(), 1e-4);
  EXPECT_EQ(set->dims, Vec3i(32, 28, 24));
  EXPECT_NEAR(set->columns.col(1).norm(), 0.6f, 1e-4);
  EXPECT_EQ(set->status["sequence"], 7);
  expect_mesh_on_label_boundary(*set);
  EXPECT_FALSE(client.read(300ms).has_value());  // the skipped line sent nothing
  server.stop();
}

TEST(IgtlServer, LateJoinerGetsTheLatestAndClientMessagesNeverBreakTheLink) {
  RunStats stats;
  IgtlServer server(stats);
  const int port = server.start({"127.0.0.1", 0});
  for (std::uint64_t s = 1; s <= 3; ++s) {
    const ProcessedVolume v = oblique_ball(s);
    server.publish(v, status_line(s).dump());  // packed before the client connects
  }
  TestClient late(port);
  ASSERT_TRUE(late.connected());
  auto set = read_set(late);
  ASSERT_TRUE(set);
  EXPECT_EQ(set->status["sequence"], 3);  // the latest, at once
  // Slicer's version-2 STATUS on connect (extended header and metadata in its body), an unknown
  // type, then a GET_ query, which is answered with the latest set.
  late.send(2, "STATUS", std::string(12 + 30 + 8, '\x01'));
  late.send(1, "NONSENSE", std::string(100000, 'x'));
  late.send(1, "GET_IMAGE", "");
  set = read_set(late);
  ASSERT_TRUE(set);
  EXPECT_EQ(set->status["sequence"], 3);
  const ProcessedVolume v = oblique_ball(4);
  server.on_line(status_line(4), &v);
  set = read_set(late);
  ASSERT_TRUE(set);
  EXPECT_EQ(set->status["sequence"], 4);
  server.stop();
}

TEST(IgtlServer, AStalledClientDropsOldSetsWhileOthersGetEveryOne) {
  RunStats stats;
  IgtlServer server(stats);
  const int port = server.start({"127.0.0.1", 0});
  TestClient stalled(port, 4096);  // connects and never reads
  std::vector<std::unique_ptr<TestClient>> readers;
  for (int i = 0; i < 4; ++i) readers.push_back(std::make_unique<TestClient>(port));
  std::this_thread::sleep_for(200ms);
  EXPECT_EQ(stats.status_json()["igtl"]["clients"], 5);
  constexpr int kSets = 150;  // 3.5 MB: more than the kernel buffers of the stalled client hold
  for (int s = 1; s <= kSets; ++s) {
    const ProcessedVolume v = oblique_ball(s);
    server.on_line(status_line(s), &v);  // returns at once whatever the stalled client does
    for (auto& r : readers) {
      auto set = read_set(*r);
      ASSERT_TRUE(set) << "set " << s;
      EXPECT_EQ(set->status["sequence"], s);
    }
  }
  std::this_thread::sleep_for(200ms);
  const auto igtl = stats.status_json()["igtl"];
  EXPECT_GT(igtl["dropped"].get<int>(), 0);  // the stalled one fell behind and lost old sets
  EXPECT_GE(igtl["sent"].get<int>(), 4 * kSets);
  // A client that goes away is noticed and cleaned up.
  readers.clear();
  for (int i = 0; i < 50 && stats.status_json()["igtl"]["clients"] != 1; ++i) {
    const ProcessedVolume v = oblique_ball(100 + i);
    server.on_line(status_line(100 + i), &v);
    std::this_thread::sleep_for(50ms);
  }
  EXPECT_EQ(stats.status_json()["igtl"]["clients"], 1);
  server.stop();
}
