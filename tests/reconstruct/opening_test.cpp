#include <gtest/gtest.h>

#include "shapes.h"

namespace sonomesh::reconstruct {
namespace {

Vec3f unit_normal(const Mesh& m, const std::array<std::uint32_t, 3>& t) {
  return (m.vertices[t[1]] - m.vertices[t[0]])
      .cross(m.vertices[t[2]] - m.vertices[t[0]])
      .normalized();
}
float area(const Mesh& m, const std::array<std::uint32_t, 3>& t) {
  return 0.5f *
         (m.vertices[t[1]] - m.vertices[t[0]]).cross(m.vertices[t[2]] - m.vertices[t[0]]).norm();
}
bool has(const std::array<std::uint32_t, 3>& t, std::uint32_t v) {
  return t[0] == v || t[1] == v || t[2] == v;
}

TEST(OrientedSamples, SphereNormalsPointOutwardWithAreaWeights) {
  const Vec3f c(1, 2, 3);
  const Mesh m = test::uv_sphere(c, 5.0f, 24, 16);
  const PointCloud s = oriented_samples(m);
  ASSERT_EQ(s.points.size(), m.vertices.size());
  double total = 0.0, mesh_area = 0.0;
  for (std::size_t i = 0; i < s.points.size(); ++i) {
    EXPECT_NEAR(s.normals[i].norm(), 1.0f, 1e-5f);
    EXPECT_GT(s.normals[i].dot((s.points[i] - c).normalized()), 0.95f);
    total += s.area_mm2[i];
  }
  for (const auto& t : m.triangles) mesh_area += area(m, t);
  EXPECT_NEAR(total, mesh_area, 1e-3 * mesh_area);
}

TEST(OpenBalloon, RemovesTypeOneVerticesAndTheirTriangles) {
  const Mesh m = test::uv_sphere(Vec3f::Zero(), 5.0f, 10, 11);
  std::vector<StopReason> stop(m.vertices.size(), StopReason::Boundary);
  stop[0] = StopReason::SelfIntersection;  // north pole
  stop[5] = StopReason::SelfIntersection;  // one vertex of the first ring
  stop[40] = StopReason::Curvature;        // other reasons stay
  const PointCloud s = open_balloon(m, stop);
  EXPECT_EQ(s.points.size(), m.vertices.size() - 2);
  for (const auto& p : s.points) {
    EXPECT_NE(p, m.vertices[0]);
    EXPECT_NE(p, m.vertices[5]);
  }
  // Area weights: a third of every remaining triangle, so they sum to the remaining area.
  double kept_area = 0.0, total = 0.0;
  for (const auto& t : m.triangles)
    if (!has(t, 0) && !has(t, 5)) kept_area += area(m, t);
  for (float a : s.area_mm2) total += a;
  EXPECT_NEAR(total, kept_area, 1e-4 * kept_area);
}

TEST(OpenBalloon, RimNormalsComeFromTheRemainingTriangles) {
  const Mesh m = test::uv_sphere(Vec3f::Zero(), 5.0f, 10, 11);
  std::vector<StopReason> stop(m.vertices.size(), StopReason::Boundary);
  stop[0] = StopReason::SelfIntersection;
  const PointCloud opened = open_balloon(m, stop);
  const PointCloud plain = oriented_samples(m);
  // Vertex 3 (first ring) lost its two cap triangles: its normal is the normalised sum of the
  // unit normals of the triangles that remain, tilted away from the pole.
  Vec3f expected = Vec3f::Zero();
  for (const auto& t : m.triangles)
    if (has(t, 3) && !has(t, 0)) expected += unit_normal(m, t);
  expected.normalize();
  const auto it = std::find(opened.points.begin(), opened.points.end(), m.vertices[3]);
  ASSERT_NE(it, opened.points.end());
  const std::size_t i = it - opened.points.begin();
  EXPECT_LT((opened.normals[i] - expected).norm(), 1e-5f);
  EXPECT_GT((opened.normals[i] - plain.normals[3]).norm(), 1e-2f);  // it did change
  // A vertex far from the opening keeps its normal.
  const auto far = std::find(opened.points.begin(), opened.points.end(), m.vertices[60]);
  ASSERT_NE(far, opened.points.end());
  EXPECT_LT((opened.normals[far - opened.points.begin()] - plain.normals[60]).norm(), 1e-6f);
}

TEST(OpenBalloon, OpenedSphereReconstructsToAClosedSphere) {
  const Mesh m = test::uv_sphere(Vec3f::Zero(), 8.0f, 48, 32);
  std::vector<StopReason> stop(m.vertices.size(), StopReason::Boundary);
  for (std::size_t v = 0; v < m.vertices.size(); ++v)
    if (m.vertices[v].z() > 6.5f) stop[v] = StopReason::SelfIntersection;
  const SurfaceResult r =
      reconstruct_surface(open_balloon(m, stop), Vec3f::Zero(), {.cell_mm = 0.5f});
  EXPECT_TRUE(r.seed_enclosed);
  EXPECT_TRUE(r.topology.watertight);
  EXPECT_EQ(r.topology.genus, 0);
}

TEST(OpenBalloon, RejectsMismatchedStopArray) {
  const Mesh m = test::uv_sphere(Vec3f::Zero(), 5.0f, 10, 11);
  EXPECT_THROW(open_balloon(m, std::vector<StopReason>(3)), std::invalid_argument);
}

}  // namespace
}  // namespace sonomesh::reconstruct
