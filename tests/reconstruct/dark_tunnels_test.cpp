// A tunnel through the target's own darkness is filled; one round a bright needle stays.
#include <gtest/gtest.h>

#include <Eigen/Geometry>
#include <algorithm>
#include <array>
#include <cmath>
#include <random>
#include <vector>

#include "reconstruct/reconstruct.h"

namespace sonomesh::reconstruct {
namespace {

using volume::Vec3f;
using volume::Vec3i;

// The levels the pipeline passes for the images below: the inside 20, the tissue 100.
constexpr TunnelLevels kLevels{60.0f, 20.0f, 100.0f};

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
  EXPECT_TRUE(close_dark_tunnels(s, p.seed_mm, p.image, kLevels));
  EXPECT_EQ(s.topology.genus, 0);
  EXPECT_TRUE(s.topology.watertight);
  EXPECT_EQ(s.topology.components, 1);
}

TEST(DarkTunnels, ATunnelRoundABrightNeedleStays) {
  const Pierced p = pierced_ball(100.0f);
  SurfaceResult s = surface_of(p);
  const std::size_t vertices = s.mesh.vertices.size();
  EXPECT_FALSE(close_dark_tunnels(s, p.seed_mm, p.image, kLevels));
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

// A ball of radius 12 pierced along z through its centre by a bright needle, with a handle on its
// wall: a ring (radius 5, tube radius 2) half sunk into it, in a plane oblique to every axis (its
// normal along (-1, -1, 2)), over a pocket as dark as the inside. Every slice across an axis
// cuts the handle into two separate discs, so the pocket is no closed hole in any of them.
Pierced needle_and_handle() {
  Pierced p = pierced_ball(100.0f);
  const Vec3f centre(32, 32, 32);
  const Vec3f out = Vec3f(1, -1, 0).normalized(), along = Vec3f(1, 1, 1).normalized();
  const Vec3f normal = out.cross(along);
  const Vec3f ring_centre = centre + 12.0f * out;
  for (int k = 0; k < 64; ++k)
    for (int j = 0; j < 64; ++j)
      for (int i = 0; i < 64; ++i) {
        const Vec3f q(i, j, k);
        const Vec3f d = q - centre, r = q - ring_centre;
        const float height = r.dot(normal);
        const float radial = (r - height * normal).norm();
        const bool needle = std::hypot(d.x(), d.y()) < 2.5f;
        const bool ball = d.norm() < 12.0f;
        const bool ring = std::hypot(radial - 5.0f, height) < 2.0f;
        const bool pocket = !ball && !ring && radial < 5.0f && std::abs(height) < 2.0f;
        const std::size_t at = p.chi.linear_index(i, j, k);
        p.chi.f32()[at] = (ball || ring) && !needle ? 1.0f : 0.0f;
        p.image.f32()[at] = needle || !(ball || ring || pocket) ? 100.0f : 20.0f;
      }
  p.seed_mm = Vec3f(26, 38, 32);  // inside, off the needle
  return p;
}

TEST(DarkTunnels, AHandleNoSliceClosesIsFilledAndTheNeedleStays) {
  const Pierced p = needle_and_handle();
  SurfaceResult s = surface_of(p);
  ASSERT_EQ(s.topology.genus, 2);
  volume::Volume chi = p.chi;
  fill_dark_tunnels(chi, 0.5f, 1.0f, p.image, 60.0f);
  bool enclosed = false;
  EXPECT_EQ(
      analyze_topology(component_enclosing(marching_cubes(chi, 0.5f), p.seed_mm, &enclosed)).genus,
      2)
      << "the slices close the handle: the test does not reach the closing";
  EXPECT_TRUE(close_dark_tunnels(s, p.seed_mm, p.image, kLevels));
  EXPECT_EQ(s.topology.genus, 1);  // the needle's
  EXPECT_TRUE(s.topology.watertight);
  EXPECT_LT(volume::sample_mm(s.indicator, Vec3f(32, 32, 32)), 0.5f);  // on the needle
}

// A ball of radius 12 pierced along z through its centre by a bright needle, with a sheet of
// outside `thickness` cells thick from the needle's tunnel to the wall (from y = 32, x < 32) over
// a stretch of the needle (28 ≤ z ≤ 36): where the balloon's fronts met round the needle. Its
// cells read 60, a grain of the inside, above the closing's level and under the tissue's. The
// sheet meets the surface on two sides, so it is a handle.
Pierced needle_and_sheet(int thickness = 2) {
  Pierced p = pierced_ball(200.0f);
  for (int k = 28; k <= 36; ++k)
    for (int j = 32; j < 32 + thickness; ++j)
      for (int i = 0; i < 32; ++i) {
        const std::size_t at = p.chi.linear_index(i, j, k);
        if (p.chi.f32()[at] < 0.5f || Vec3f(i - 32.0f, j - 32.0f, k - 32.0f).norm() > 12.0f)
          continue;
        p.chi.f32()[at] = 0.0f;
        p.image.f32()[at] = 60.0f;
      }
  return p;
}

TEST(DarkTunnels, ASheetWhereTheFrontsMetIsFilledAndTheNeedleStays) {
  const Pierced p = needle_and_sheet();
  SurfaceResult s = surface_of(p);
  ASSERT_EQ(s.topology.genus, 2);
  EXPECT_TRUE(close_dark_tunnels(s, p.seed_mm, p.image, kLevels));
  EXPECT_EQ(s.topology.genus, 1);  // the needle's
  EXPECT_TRUE(s.topology.watertight);
  EXPECT_GT(volume::sample_mm(s.indicator, Vec3f(24, 32.5f, 32)), 0.5f);  // the sheet
  EXPECT_LT(volume::sample_mm(s.indicator, Vec3f(32, 32, 32)), 0.5f);     // on the needle
}

TEST(DarkTunnels, AThickerSheetAsksForTheWiderCube) {
  for (const int widest : {2, kWidestSheetCells}) {
    const Pierced p = needle_and_sheet(5);
    SurfaceResult s = surface_of(p);
    ASSERT_EQ(s.topology.genus, 2);
    TunnelLevels levels = kLevels;
    levels.widest_sheet_cells = widest;
    EXPECT_EQ(close_dark_tunnels(s, p.seed_mm, p.image, levels), widest > 2) << widest;
    EXPECT_EQ(s.topology.genus, widest > 2 ? 1 : 2) << widest;
  }
}

TEST(DarkTunnels, ASheetAsBrightAsTheTissueStays) {
  Pierced p = needle_and_sheet();
  for (float& v : p.image.f32())
    if (v == 60.0f) v = 100.0f;
  SurfaceResult s = surface_of(p);
  EXPECT_FALSE(close_dark_tunnels(s, p.seed_mm, p.image, kLevels));
  EXPECT_EQ(s.topology.genus, 2);
}

// The slices' holes the plain way: per axis in turn, per slice of the inside cells' box (grown by
// one cell, clipped to the grid), a flood over the outside cells from each one not yet seen; a
// region that never reaches the slice's edge is a hole and becomes inside. Returns the cells
// filled, sorted.
std::vector<std::size_t> flooded_holes(volume::Volume chi) {
  const Vec3i n = chi.dims();
  auto in = [&](const Vec3i& c) { return chi.f32()[chi.linear_index(c.x(), c.y(), c.z())] > 0.5f; };
  Vec3i lo = n, hi = Vec3i::Constant(-1);
  for (int k = 0; k < n.z(); ++k)
    for (int j = 0; j < n.y(); ++j)
      for (int i = 0; i < n.x(); ++i)
        if (in(Vec3i(i, j, k))) {
          lo = lo.cwiseMin(Vec3i(i, j, k));
          hi = hi.cwiseMax(Vec3i(i, j, k));
        }
  lo = (lo - Vec3i::Ones()).cwiseMax(Vec3i::Zero());
  hi = (hi + Vec3i::Ones()).cwiseMin(n - Vec3i::Ones());
  std::vector<std::size_t> filled;
  for (int axis = 0; axis < 3; ++axis) {
    const int a = (axis + 1) % 3, b = (axis + 2) % 3;
    for (int s = lo[axis]; s <= hi[axis]; ++s) {
      std::vector<std::uint8_t> seen(chi.voxel_count(), 0);
      for (int v0 = lo[b]; v0 <= hi[b]; ++v0)
        for (int u0 = lo[a]; u0 <= hi[a]; ++u0) {
          Vec3i c0;
          c0[axis] = s, c0[a] = u0, c0[b] = v0;
          if (in(c0) || seen[chi.linear_index(c0.x(), c0.y(), c0.z())]) continue;
          std::vector<Vec3i> region, stack{c0};
          seen[chi.linear_index(c0.x(), c0.y(), c0.z())] = 1;
          bool edge = false;
          while (!stack.empty()) {
            const Vec3i c = stack.back();
            stack.pop_back();
            region.push_back(c);
            edge = edge || c[a] == lo[a] || c[a] == hi[a] || c[b] == lo[b] || c[b] == hi[b];
            for (const Vec3i& d : std::array<Vec3i, 4>{Vec3i::Unit(a), -Vec3i::Unit(a),
                                                       Vec3i::Unit(b), -Vec3i::Unit(b)}) {
              const Vec3i e = c + d;
              if (e[a] < lo[a] || e[a] > hi[a] || e[b] < lo[b] || e[b] > hi[b] || in(e)) continue;
              if (std::exchange(seen[chi.linear_index(e.x(), e.y(), e.z())], 1)) continue;
              stack.push_back(e);
            }
          }
          if (edge) continue;
          for (const Vec3i& c : region) {
            filled.push_back(chi.linear_index(c.x(), c.y(), c.z()));
            chi.f32()[filled.back()] = 1.0f;
          }
        }
    }
  }
  std::sort(filled.begin(), filled.end());
  return filled;
}

TEST(DarkTunnels, FillsTheHolesOfEverySliceAndNothingElse) {
  // Random cells inside (three in five) in a block that reaches the grid's edge on four sides
  // (the box is clipped there, its rim not all outside): slices with many holes of every shape,
  // some touching the box's edge, across all three axes.
  volume::Volume chi(Vec3i(30, 26, 22), Vec3f(1, 1, 1), Vec3f(0, 0, 0), volume::VoxelType::Float32);
  std::mt19937 random(7);
  std::bernoulli_distribution inside(0.6);
  for (int k = 3; k < 22; ++k)
    for (int j = 0; j < 26; ++j)
      for (int i = 0; i < 27; ++i) chi.f32()[chi.linear_index(i, j, k)] = inside(random);
  const std::vector<std::size_t> expected = flooded_holes(chi);
  ASSERT_GT(expected.size(), 100u) << "too few holes to compare";
  const volume::Volume dark(chi.dims(), chi.spacing_mm(), chi.origin_mm(),
                            volume::VoxelType::Float32);
  for (const int threads : {1, 2}) {
    volume::Volume filled_chi = chi;
    std::vector<std::size_t> filled;
    for (const FilledCell& c : fill_dark_tunnels(filled_chi, 0.5f, 1.0f, dark, 1.0f, threads))
      filled.push_back(c.index);
    std::sort(filled.begin(), filled.end());
    EXPECT_EQ(filled, expected) << threads << " threads";
  }
}

}  // namespace
}  // namespace sonomesh::reconstruct
