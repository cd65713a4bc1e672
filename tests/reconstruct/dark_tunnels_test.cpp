// A tunnel through the target's own darkness is filled; one round a bright needle stays.
#include <gtest/gtest.h>

#include "reconstruct/reconstruct.h"

namespace sonomesh::reconstruct {
namespace {

using volume::Vec3f;
using volume::Vec3i;

// A ball of radius 12 voxels pierced along z by a tunnel of radius 2.5: χ 1 inside, 0 outside;
// the image 20 inside the ball, 100 in the tissue, and `tunnel_level` in the tunnel.
struct Pierced {
  volume::Volume chi, image;
  Vec3f seed_mm{38, 32, 32};  // inside the ball, off the tunnel
};

Pierced pierced_ball(float tunnel_level) {
  Pierced p{
      volume::Volume(Vec3i(64, 64, 64), Vec3f(1, 1, 1), Vec3f(0, 0, 0), volume::VoxelType::Float32),
      volume::Volume(Vec3i(64, 64, 64), Vec3f(1, 1, 1), Vec3f(0, 0, 0),
                     volume::VoxelType::Float32)};
  for (int k = 0; k < 64; ++k)
    for (int j = 0; j < 64; ++j)
      for (int i = 0; i < 64; ++i) {
        const Vec3f d(i - 32.0f, j - 32.0f, k - 32.0f);
        const bool ball = d.norm() < 12.0f;
        const bool tunnel = std::hypot(d.x(), d.y()) < 2.5f;
        const std::size_t at = p.chi.linear_index(i, j, k);
        p.chi.f32()[at] = ball && !tunnel ? 1.0f : 0.0f;
        p.image.f32()[at] = tunnel && ball ? tunnel_level : (ball ? 20.0f : 100.0f);
      }
  return p;
}

SurfaceResult surface_of(const Pierced& p) {
  SurfaceResult s;
  s.indicator = p.chi;
  s.iso = 0.5f;
  s.mesh = component_enclosing(marching_cubes(p.chi, s.iso), p.seed_mm, &s.seed_enclosed);
  s.topology = analyze_topology(s.mesh);
  return s;
}

TEST(DarkTunnels, ATunnelAsDarkAsTheInsideIsFilled) {
  const Pierced p = pierced_ball(20.0f);
  SurfaceResult s = surface_of(p);
  ASSERT_EQ(s.topology.genus, 1);
  EXPECT_TRUE(close_dark_tunnels(s, p.seed_mm, p.image, 60.0f));
  EXPECT_EQ(s.topology.genus, 0);
  EXPECT_TRUE(s.topology.watertight);
  EXPECT_EQ(s.topology.components, 1);
}

TEST(DarkTunnels, ATunnelRoundABrightNeedleStays) {
  const Pierced p = pierced_ball(100.0f);
  SurfaceResult s = surface_of(p);
  const std::size_t vertices = s.mesh.vertices.size();
  EXPECT_FALSE(close_dark_tunnels(s, p.seed_mm, p.image, 60.0f));
  EXPECT_EQ(s.topology.genus, 1);
  EXPECT_EQ(s.mesh.vertices.size(), vertices);
}

TEST(DarkTunnels, CountsTheCellsItFills) {
  Pierced p = pierced_ball(20.0f);
  const int filled = static_cast<int>(fill_dark_tunnels(p.chi, 0.5f, 1.0f, p.image, 60.0f).size());
  // The tunnel's cells inside the ball, seen from the z slices (and from x and y, where the
  // ball's cross-section encloses them): at least its volume once.
  EXPECT_GT(filled, 300);
  EXPECT_GT(volume::sample_mm(p.chi, Vec3f(32, 32, 32)), 0.5f);
}

}  // namespace
}  // namespace sonomesh::reconstruct
