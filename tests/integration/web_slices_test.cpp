// /slices: the mesh's contour in a slice plane lies on the surface's cross-section, and the
// rendered PNGs decode to images of the volume's proportions with the contour drawn in red.
#include <gtest/gtest.h>

#include <cmath>
#include <opencv2/core.hpp>
#include <opencv2/imgcodecs.hpp>

#include "daemon/internal/slice_renderer.h"

namespace {

using sonomesh::daemon::mesh_contour;
using sonomesh::daemon::SliceAxis;
using sonomesh::daemon::SliceRenderer;
using sonomesh::volume::Vec3f;
using sonomesh::volume::Vec3i;
using sonomesh::volume::Volume;
using sonomesh::volume::VoxelType;

// An icosphere-like UV sphere of `radius_mm` around `centre_mm`.
sonomesh::segment::Mesh sphere(const Vec3f& centre_mm, float radius_mm, int rings = 48) {
  sonomesh::segment::Mesh m;
  const int segments = 2 * rings;
  for (int r = 0; r <= rings; ++r) {
    const float theta = static_cast<float>(M_PI) * r / rings;
    for (int s = 0; s < segments; ++s) {
      const float phi = 2.0f * static_cast<float>(M_PI) * s / segments;
      m.vertices.push_back(centre_mm + radius_mm * Vec3f(std::sin(theta) * std::cos(phi),
                                                         std::sin(theta) * std::sin(phi),
                                                         std::cos(theta)));
    }
  }
  auto at = [&](int r, int s) { return static_cast<std::uint32_t>(r * segments + s % segments); };
  for (int r = 0; r < rings; ++r) {
    for (int s = 0; s < segments; ++s) {
      m.triangles.push_back({at(r, s), at(r + 1, s), at(r + 1, s + 1)});
      m.triangles.push_back({at(r, s), at(r + 1, s + 1), at(r, s + 1)});
    }
  }
  return m;
}

TEST(SliceRenderer, ContourLiesOnTheCrossSectionAndIsDrawn) {
  // 40 x 48 x 56 voxels of 0.5 mm; a dark sphere of 6 mm radius in bright tissue.
  Volume volume(Vec3i(40, 48, 56), Vec3f(0.5f, 0.5f, 0.5f), Vec3f(-10, -12, -14), VoxelType::UInt8);
  const Vec3f centre_mm(0.5f, -1.0f, 1.5f);
  const float radius_mm = 6.0f;
  for (int k = 0; k < 56; ++k)
    for (int j = 0; j < 48; ++j)
      for (int i = 0; i < 40; ++i) {
        const Vec3f p = volume.index_to_mm(Vec3f(i, j, k));
        volume.u8()[volume.linear_index(i, j, k)] = (p - centre_mm).norm() < radius_mm ? 30 : 200;
      }
  const auto mesh = sphere(centre_mm, radius_mm);
  // Axial plane 2 mm above the centre: a circle of radius sqrt(36 - 4) mm, in voxels.
  const float plane_vox = volume.mm_to_index(centre_mm + Vec3f(0, 0, 2)).z();
  const auto segments = mesh_contour(mesh, volume, SliceAxis::Axial, plane_vox);
  ASSERT_GT(segments.size(), 50u);
  const Vec3f c = volume.mm_to_index(centre_mm);
  const float expected_vox = std::sqrt(36.0f - 4.0f) / 0.5f;
  for (const auto& s : segments) {
    for (const auto& p : {s.a, s.b}) {
      const float r = std::hypot(p.u - c.x(), p.v - c.y());
      EXPECT_NEAR(r, expected_vox, 0.1f);  // the polygon's chords sag at most ~0.02 voxel
    }
  }
  // Outside the sphere's extent the plane cuts nothing.
  EXPECT_TRUE(mesh_contour(mesh, volume, SliceAxis::Axial, c.z() + 13.0f).empty());

  SliceRenderer renderer;
  EXPECT_FALSE(renderer.png(SliceAxis::Axial));
  EXPECT_TRUE(renderer.info().is_null());
  renderer.update(volume, mesh, centre_mm, 7);
  EXPECT_EQ(renderer.info()["sequence"], 7);
  EXPECT_EQ(renderer.info()["seed_index"], nlohmann::json({21, 22, 31}));
  for (SliceAxis axis : {SliceAxis::Axial, SliceAxis::Coronal, SliceAxis::Sagittal}) {
    const auto png = renderer.png(axis);
    ASSERT_TRUE(png);
    const cv::Mat image =
        cv::imdecode(std::vector<uchar>(png->begin(), png->end()), cv::IMREAD_COLOR);
    ASSERT_FALSE(image.empty());
    // The largest extent (56 voxels, z) maps to kTargetEdgePx; the others keep the proportions.
    const int w = axis == SliceAxis::Sagittal ? 48 : 40, h = axis == SliceAxis::Axial ? 48 : 56;
    const double px_per_vox = SliceRenderer::kTargetEdgePx / 56.0;
    EXPECT_NEAR(image.cols, w * px_per_vox, 1.0);
    EXPECT_NEAR(image.rows, h * px_per_vox, 1.0);
    // Red contour pixels (B, G low, R high) exist; grey tissue and dark target have R == B.
    int red = 0;
    for (int y = 0; y < image.rows; ++y)
      for (int x = 0; x < image.cols; ++x) {
        const cv::Vec3b p = image.at<cv::Vec3b>(y, x);
        if (p[2] > 150 && p[2] > p[0] + 80) ++red;
      }
    EXPECT_GT(red, 100) << sonomesh::daemon::to_string(axis);
  }
}

}  // namespace
