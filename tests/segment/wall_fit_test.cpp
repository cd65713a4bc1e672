// The wall fit (segment::fit_to_wall): a surface a voxel short of the wall, or beyond it, goes to
// the wall; nothing moves where there is no wall; no vertex moves further than the bound; along
// a probe's beam the crossing lies lower on the rise.
#include <gtest/gtest.h>

#include <cmath>
#include <stdexcept>
#include <vector>

#include "../reconstruct/shapes.h"
#include "mesh/mesh.h"
#include "segment/segment.h"
#include "sim/sim.h"

using namespace sonomesh;
using segment::Mesh;
using volume::Vec3f;

namespace {

struct Target {
  sim::Phantom phantom;
  volume::Volume smoothed;
  Vec3f centre_mm = Vec3f::Zero();
  float radius_mm = 0.0f;  // of the sphere with the truth's voxel count
  float vox_mm = 0.0f;
  segment::BalloonStats levels;
};

Target speckled_sphere() {
  Target t;
  t.phantom = sim::make_phantom({.phantom = "sphere", .size_vox = 64, .speckle = 0.5f});
  t.vox_mm = t.phantom.image.spacing_mm().minCoeff();
  t.smoothed = volume::smooth_gaussian(t.phantom.image, t.vox_mm);
  const volume::Volume& truth = t.phantom.truth;
  double inside = 0, outside = 0, count = 0, count_out = 0;
  Vec3f sum = Vec3f::Zero();
  for (int k = 0; k < truth.dims().z(); ++k)
    for (int j = 0; j < truth.dims().y(); ++j)
      for (int i = 0; i < truth.dims().x(); ++i) {
        const float value = t.smoothed.value(i, j, k);
        if (truth.value(i, j, k) > 0.5f) {
          sum += truth.index_to_mm(Vec3f(i, j, k));
          inside += value, ++count;
        } else {
          outside += value, ++count_out;
        }
      }
  t.centre_mm = sum / static_cast<float>(count);
  t.radius_mm = std::cbrt(3.0 * count / (4.0 * M_PI)) * t.vox_mm;
  t.levels.seed_level = static_cast<float>(inside / count);
  t.levels.tissue_level = static_cast<float>(outside / count_out);
  return t;
}

// Mean and largest distance of the vertices from the sphere's wall, in voxels.
std::pair<double, double> wall_distance_vox(const Mesh& m, const Target& t) {
  double sum = 0, most = 0;
  for (const Vec3f& p : m.vertices) {
    const double d = std::abs((p - t.centre_mm).norm() - t.radius_mm) / t.vox_mm;
    sum += d, most = std::max(most, d);
  }
  return {sum / static_cast<double>(m.vertices.size()), most};
}

TEST(WallFit, ASurfaceShortOfTheWallOrBeyondItGoesToTheWall) {
  const Target t = speckled_sphere();
  for (const float offset_vox : {-1.0f, 0.8f}) {
    const Mesh start =
        reconstruct::test::uv_sphere(t.centre_mm, t.radius_mm + offset_vox * t.vox_mm, 48, 24);
    const Mesh fitted = segment::fit_to_wall(t.smoothed, start, t.levels);
    ASSERT_EQ(fitted.triangles, start.triangles);
    const auto [before, before_most] = wall_distance_vox(start, t);
    const auto [after, after_most] = wall_distance_vox(fitted, t);
    EXPECT_NEAR(before, std::abs(offset_vox), 0.05) << offset_vox;
    EXPECT_LT(after, 0.25) << after << " vox, started " << offset_vox << " vox off the wall";
    EXPECT_LT(after_most, 0.8) << offset_vox;
  }
}

TEST(WallFit, NoWallNoMove) {
  Target t = speckled_sphere();
  for (float& v : t.smoothed.f32()) v = 50.0f;
  const Mesh start = reconstruct::test::uv_sphere(t.centre_mm, t.radius_mm, 32, 16);
  EXPECT_EQ(segment::fit_to_wall(t.smoothed, start, t.levels).vertices, start.vertices);
}

TEST(WallFit, NoVertexMovesFurtherThanTheBound) {
  const Target t = speckled_sphere();
  const Mesh start = reconstruct::test::uv_sphere(t.centre_mm, t.radius_mm - 3 * t.vox_mm, 32, 16);
  segment::WallFitOptions options;
  options.reach_vox = 4.0f;
  options.max_move_vox = 1.0f;
  const Mesh fitted = segment::fit_to_wall(t.smoothed, start, t.levels, options);
  double most = 0;
  for (std::size_t v = 0; v < start.vertices.size(); ++v)
    most = std::max(most, double((fitted.vertices[v] - start.vertices[v]).norm()));
  EXPECT_LE(most, 1.0001 * t.vox_mm);
  EXPECT_GT(most, 0.9 * t.vox_mm) << "the wall was in reach: the bound held the vertices back";
}

// With a probe's apex, the vertices whose wall runs along the beam cross lower on the rise, and
// so further in; those facing the probe cross half way as without one.
TEST(WallFit, AlongTheBeamTheCrossingLiesLowerOnTheRise) {
  const Target t = speckled_sphere();
  const Mesh start = reconstruct::test::uv_sphere(t.centre_mm, t.radius_mm, 48, 24);
  segment::WallFitOptions beam;
  beam.probe_apex_mm = t.centre_mm - Vec3f(0.0f, 0.0f, 40.0f * t.vox_mm);
  const Mesh half = segment::fit_to_wall(t.smoothed, start, t.levels);
  const Mesh lower = segment::fit_to_wall(t.smoothed, start, t.levels, beam);
  const std::vector<Vec3f> normal = mesh::vertex_normals(start);
  double along_in_vox = 0, facing_in_vox = 0;
  int along = 0, facing = 0;
  for (std::size_t v = 0; v < start.vertices.size(); ++v) {
    const double in_vox =
        ((half.vertices[v] - t.centre_mm).norm() - (lower.vertices[v] - t.centre_mm).norm()) /
        t.vox_mm;
    if (segment::faces_probe(start.vertices[v], normal[v], *beam.probe_apex_mm))
      facing_in_vox += in_vox, ++facing;
    else
      along_in_vox += in_vox, ++along;
  }
  ASSERT_GT(along, 0);
  ASSERT_GT(facing, 0);
  EXPECT_GT(along_in_vox / along, 0.05);
  EXPECT_LT(std::abs(facing_in_vox / facing), 0.02);
}

TEST(WallFit, RejectsBadInput) {
  const Target t = speckled_sphere();
  Mesh bad = reconstruct::test::uv_sphere(t.centre_mm, t.radius_mm, 8, 4);
  EXPECT_THROW(segment::fit_to_wall(volume::Volume{}, bad, t.levels), std::invalid_argument);
  EXPECT_THROW(segment::fit_to_wall(t.smoothed, bad, segment::BalloonStats{}),
               std::invalid_argument);
  segment::WallFitOptions options;
  options.step_vox = 0.0f;
  EXPECT_THROW(segment::fit_to_wall(t.smoothed, bad, t.levels, options), std::invalid_argument);
  options = {};
  options.along_beam_fraction = 1.0f;
  EXPECT_THROW(segment::fit_to_wall(t.smoothed, bad, t.levels, options), std::invalid_argument);
  bad.triangles.push_back({0, 1, 9999});
  EXPECT_THROW(segment::fit_to_wall(t.smoothed, bad, t.levels), std::invalid_argument);
}

}  // namespace
