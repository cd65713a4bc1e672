// The warm start's start mesh (segment/internal/warm_interior.h): the previous balloon's interior
// eroded by the inset, as one closed genus-0 surface inside it; an interior with a tunnel gives
// no start mesh.
#include "segment/internal/warm_interior.h"

#include <gtest/gtest.h>

#include <cmath>
#include <limits>
#include <vector>

#include "segment/segment.h"
#include "sim/sim.h"

using namespace sonomesh;
using segment::Mesh;
using volume::Vec3f;

namespace {

constexpr float kVoxMm = 0.5f;
const segment::internal::RemeshLimits kLimits{0.8f * 1.75f * kVoxMm, 4.0f / 3.0f * 1.75f * kVoxMm};

float nearest_mm(const Mesh& m, const Vec3f& p) {
  float best = std::numeric_limits<float>::max();
  for (const Vec3f& q : m.vertices) best = std::min(best, (q - p).norm());
  return best;
}

// A torus of radii `r_big` and `r_small` mm about the z axis, outward oriented.
Mesh torus(float r_big, float r_small, const Vec3f& centre) {
  constexpr int kU = 64, kV = 24;
  Mesh m;
  for (int u = 0; u < kU; ++u)
    for (int v = 0; v < kV; ++v) {
      const float a = 2.0f * float(M_PI) * u / kU, b = 2.0f * float(M_PI) * v / kV;
      const float r = r_big + r_small * std::cos(b);
      m.vertices.push_back(centre + Vec3f(r * std::cos(a), r * std::sin(a), r_small * std::sin(b)));
    }
  auto at = [](int u, int v) { return std::uint32_t((u % kU) * kV + v % kV); };
  for (int u = 0; u < kU; ++u)
    for (int v = 0; v < kV; ++v) {
      m.triangles.push_back({at(u, v), at(u + 1, v), at(u + 1, v + 1)});
      m.triangles.push_back({at(u, v), at(u + 1, v + 1), at(u, v + 1)});
    }
  return m;
}

// The cold balloon on the needle-pierced cyst met itself behind the needle; its eroded interior
// is one genus-0 surface inside it, about the inset away from it.
TEST(WarmInterior, StartsInsideTheBalloonOfANeedlePiercedCyst) {
  const sim::Phantom p = sim::make_phantom({.phantom = "cyst-needle", .size_vox = 64});
  const segment::BalloonResult cold = segment::inflate_balloon(p.image, kVoxMm, p.seed_mm);
  ASSERT_TRUE(cold.error.empty()) << cold.error;
  ASSERT_GT(cold.stats.stop_counts[int(segment::StopReason::SelfIntersection)], 0);
  const float inset_mm = 2.0f * kVoxMm;
  segment::internal::BalloonMesh start;
  const std::string why =
      segment::internal::eroded_start_mesh(cold.mesh, p.seed_mm, inset_mm, kVoxMm, kLimits, start);
  ASSERT_TRUE(why.empty()) << why;
  EXPECT_EQ(segment::internal::validate(start), "");
  const Mesh m = segment::internal::to_plain_mesh(start);
  EXPECT_EQ(mesh::euler_characteristic(m), 2);
  int outside = 0, too_close = 0;
  for (const Vec3f& v : m.vertices) {
    outside += !mesh::encloses(cold.mesh, v);
    too_close += nearest_mm(cold.mesh, v) < inset_mm - kVoxMm;
  }
  EXPECT_EQ(outside, 0);
  EXPECT_EQ(too_close, 0);
  // The inset takes a shell, not the target (64³: a 2-voxel shell of a cyst 13 voxels in
  // radius, and the groove round the needle widened, leave about 40 % of it).
  EXPECT_GT(mesh::enclosed_volume_ml(m), 0.3 * mesh::enclosed_volume_ml(cold.mesh));
}

// A solid torus stays one however far it is eroded (until it breaks): no start mesh.
TEST(WarmInterior, RefusesAnInteriorWithATunnel) {
  const Mesh ring = torus(8.0f, 4.0f, Vec3f(16.0f, 16.0f, 16.0f));
  ASSERT_EQ(mesh::euler_characteristic(ring), 0);
  segment::internal::BalloonMesh start;
  const std::string why = segment::internal::eroded_start_mesh(
      ring, Vec3f(24.0f, 16.0f, 16.0f), 2.0f * kVoxMm, kVoxMm, kLimits, start);
  EXPECT_NE(why.find("tunnel"), std::string::npos) << why;
}

// An inset deeper than the balloon's interior leaves nothing to start from.
TEST(WarmInterior, RefusesAnInsetDeeperThanTheInterior) {
  const sim::Phantom p = sim::make_phantom({.phantom = "sphere", .size_vox = 48});
  const segment::BalloonResult cold = segment::inflate_balloon(p.image, kVoxMm, p.seed_mm);
  ASSERT_TRUE(cold.error.empty()) << cold.error;
  segment::internal::BalloonMesh start;
  const std::string why =
      segment::internal::eroded_start_mesh(cold.mesh, p.seed_mm, 100.0f, kVoxMm, kLimits, start);
  EXPECT_NE(why.find("deep"), std::string::npos) << why;
}

}  // namespace
