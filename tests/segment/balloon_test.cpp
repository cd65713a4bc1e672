// The balloon (method.md §1-3) on speckled phantoms from the simulator.
#include <gtest/gtest.h>

#include <Eigen/Geometry>
#include <chrono>
#include <cmath>
#include <map>
#include <stdexcept>
#include <utility>
#include <vector>

#include "segment/segment.h"
#include "sim/sim.h"

using namespace sonomesh;
using segment::StopReason;
using volume::Vec3f;
using volume::Vec3i;

namespace {

struct Prepared {
  sim::Phantom phantom;
  volume::Volume smoothed;
  float vox_mm = 0.0f;
};

Prepared prepare(const std::string& name, int size, std::uint32_t seed = 3) {
  Prepared p;
  p.phantom = sim::make_phantom({.phantom = name, .size_vox = size, .seed = seed});
  p.vox_mm = p.phantom.image.spacing_mm().minCoeff();
  // About one voxel of smoothing, as the pipeline does (method.md §0).
  p.smoothed = volume::smooth_gaussian(p.phantom.image, p.vox_mm);
  return p;
}

// Surface samples of the voxelised truth: midpoints between 6-neighbour voxel centres with
// different labels. They lie on the staircase surface, within half a voxel of the true wall.
std::vector<Vec3f> truth_wall_mm(const volume::Volume& truth) {
  std::vector<Vec3f> out;
  const Vec3i d = truth.dims();
  const auto& t = truth.u8();
  for (int k = 0; k < d.z(); ++k)
    for (int j = 0; j < d.y(); ++j)
      for (int i = 0; i < d.x(); ++i) {
        const bool in = t[truth.linear_index(i, j, k)] != 0;
        const int nb[3][3] = {{i + 1, j, k}, {i, j + 1, k}, {i, j, k + 1}};
        for (const auto& n : nb) {
          if (n[0] >= d.x() || n[1] >= d.y() || n[2] >= d.z()) continue;
          if ((t[truth.linear_index(n[0], n[1], n[2])] != 0) != in)
            out.push_back(
                truth.index_to_mm(Vec3f(0.5f * (i + n[0]), 0.5f * (j + n[1]), 0.5f * (k + n[2]))));
        }
      }
  return out;
}

float distance_to(const std::vector<Vec3f>& samples, const Vec3f& p) {
  float best = 1e30f;
  for (const auto& s : samples) best = std::min(best, (s - p).squaredNorm());
  return std::sqrt(best);
}

bool inside_truth(const volume::Volume& truth, const Vec3f& p_mm) {
  const Vec3f u = truth.mm_to_index(p_mm);
  const Vec3i ijk(static_cast<int>(std::lround(u.x())), static_cast<int>(std::lround(u.y())),
                  static_cast<int>(std::lround(u.z())));
  if (!truth.contains_index(ijk)) return false;
  return truth.u8()[truth.linear_index(ijk.x(), ijk.y(), ijk.z())] != 0;
}

// Closed 2-manifold: every undirected edge is shared by exactly two triangles, once each way.
bool closed_and_consistently_oriented(const segment::Mesh& m) {
  std::map<std::pair<std::uint32_t, std::uint32_t>, int> directed;
  for (const auto& t : m.triangles)
    for (int k = 0; k < 3; ++k) {
      const auto a = t[k], b = t[(k + 1) % 3];
      if (a == b) return false;
      if (++directed[{a, b}] > 1) return false;
    }
  for (const auto& [e, n] : directed)
    if (!directed.count({e.second, e.first})) return false;
  return true;
}

// Surface area per vertex in units of L² (the target edge length): about 1 for a mesh that
// remeshing keeps at L. A front folded over itself, or one refined into slivers, has more vertices.
double area_per_vertex_L2(const segment::Mesh& m, float vox_mm) {
  const double edge_mm = segment::BalloonOptions{}.target_edge_vox * vox_mm;
  return mesh::surface_area_mm2(m) / static_cast<double>(m.vertices.size()) / (edge_mm * edge_mm);
}

int count(const segment::BalloonResult& r, StopReason reason) {
  return r.stats.stop_counts[static_cast<std::size_t>(reason)];
}

}  // namespace

TEST(Balloon, SettlesOnTheSphereWallWithinOneVoxel) {
  const Prepared p = prepare("sphere", 64);
  const auto r = segment::inflate_balloon(p.smoothed, p.phantom.seed_mm);
  ASSERT_EQ(r.error, "");
  EXPECT_TRUE(r.converged);
  ASSERT_EQ(r.stop.size(), r.mesh.vertices.size());
  EXPECT_TRUE(closed_and_consistently_oriented(r.mesh));
  EXPECT_EQ(segment::euler_characteristic(r.mesh), 2);

  // The true wall: centre and radius of the truth labels (volume-equivalent sphere).
  Vec3f centre = Vec3f::Zero();
  int n_in = 0;
  const Vec3i d = p.phantom.truth.dims();
  for (int k = 0; k < d.z(); ++k)
    for (int j = 0; j < d.y(); ++j)
      for (int i = 0; i < d.x(); ++i)
        if (p.phantom.truth.u8()[p.phantom.truth.linear_index(i, j, k)]) {
          centre += p.phantom.truth.index_to_mm(Vec3f(i, j, k));
          ++n_in;
        }
  centre /= static_cast<float>(n_in);
  const float voxel_volume = p.phantom.truth.spacing_mm().prod();
  const float radius_mm = std::cbrt(3.0f * n_in * voxel_volume / (4.0f * static_cast<float>(M_PI)));
  // Spec: every vertex within one voxel of the wall. Over speckle seeds 1-11 it holds for all 11
  // at 64³ (worst vertex 0.91) and 10 at 96³ (one vertex at 1.02, where the speckle moved the
  // image's own edge out); this seed's worst is 0.62. No side may dominate: the stop rule once
  // left the balloon 0.3 voxel inside on average (snap_to_wall).
  float worst_vox = 0.0f, signed_sum_vox = 0.0f;
  for (const auto& v : r.mesh.vertices) {
    const float err_vox = ((v - centre).norm() - radius_mm) / p.vox_mm;
    worst_vox = std::max(worst_vox, std::abs(err_vox));
    signed_sum_vox += err_vox;
  }
  EXPECT_LE(worst_vox, 1.0f) << "every vertex within one voxel of the wall";
  EXPECT_LT(std::abs(signed_sum_vox / static_cast<float>(r.mesh.vertices.size())), 0.2f)
      << "mean signed error, voxels";
  // One layer at the target edge length: the area is the sphere's (1.001-1.006 of 4πr² over seeds
  // 1-8), at 0.92-0.95 L² per vertex.
  EXPECT_NEAR(mesh::surface_area_mm2(r.mesh) / (4.0 * M_PI * radius_mm * radius_mm), 1.0, 0.03);
  EXPECT_NEAR(area_per_vertex_L2(r.mesh, p.vox_mm), 1.0, 0.2);

  const int n = static_cast<int>(r.mesh.vertices.size());
  EXPECT_GE(count(r, StopReason::Boundary), 0.9 * n) << "nearly all stopped by the boundary cost";
  EXPECT_EQ(count(r, StopReason::IterationLimit), 0);
  EXPECT_GT(r.stats.tau_cost_used, 0.0f);
}

TEST(Balloon, TorusStaysGenusZeroAndStopsWhereTheFrontsMeet) {
  const Prepared p = prepare("torus", 72);
  const auto r = segment::inflate_balloon(p.smoothed, p.phantom.seed_mm);
  ASSERT_EQ(r.error, "");
  EXPECT_TRUE(r.converged);
  EXPECT_TRUE(closed_and_consistently_oriented(r.mesh));
  EXPECT_EQ(segment::euler_characteristic(r.mesh), 2)
      << "the balloon itself never changes topology";

  // Torus axis: z through the volume centre (PhantomSpec default axis). The seed sits in the
  // tube; its two growing ends meet on the far side of the ring.
  const Vec3f centre = 0.5f * (p.phantom.image.min_mm() + p.phantom.image.max_mm());
  auto azimuth = [&](const Vec3f& q) { return std::atan2(q.y() - centre.y(), q.x() - centre.x()); };
  const float seed_az = azimuth(p.phantom.seed_mm);
  const auto wall = truth_wall_mm(p.phantom.truth);
  int self_stops = 0, self_near_seed_side = 0, self_on_outer_wall = 0;
  for (std::size_t i = 0; i < r.mesh.vertices.size(); ++i) {
    if (r.stop[i] != StopReason::SelfIntersection) continue;
    ++self_stops;
    const Vec3f& v = r.mesh.vertices[i];
    float delta = std::abs(azimuth(v) - seed_az);
    if (delta > static_cast<float>(M_PI)) delta = 2.0f * static_cast<float>(M_PI) - delta;
    if (delta < 0.6f * static_cast<float>(M_PI)) ++self_near_seed_side;
    // Away from the meeting plane a self-intersection stop would sit on the tube wall (the outer
    // wall); in the meeting plane the stops fill the tube's cross-section, out to the rim where
    // that plane meets the wall (the seam, within 1.5 voxels of arc, is where the fronts meet).
    const float radial = std::hypot(v.x() - centre.x(), v.y() - centre.y());
    const float outer_radius = (p.phantom.image.max_mm().x() - centre.x()) * (0.42f + 0.2f);
    const float arc_from_meeting_plane_mm = (static_cast<float>(M_PI) - delta) * radial;
    if (radial > outer_radius - 1.0f * p.vox_mm && distance_to(wall, v) < 1.0f * p.vox_mm &&
        arc_from_meeting_plane_mm > 1.5f * p.vox_mm)
      ++self_on_outer_wall;
  }
  EXPECT_GE(self_stops, 10) << "the fronts meeting across the ring must be detected";
  // One layer: the balloon's area is the torus's plus the two caps that meet (1.013-1.033 of it
  // over seeds 1-8, at 0.98-1.01 L² per vertex). Where a front folds into a double layer, as a
  // wall snap that followed speckle once made it do over 70° of a tube, the genus stays right and
  // only the area and the vertex count show it.
  const float half_extent_mm = p.phantom.image.max_mm().x() - centre.x();
  const double major_mm = 0.42 * half_extent_mm, tube_mm = 0.2 * half_extent_mm;  // sim's torus
  const double torus_and_caps_mm2 =
      4.0 * M_PI * M_PI * major_mm * tube_mm + 2.0 * M_PI * tube_mm * tube_mm;
  // (A snap without its slope threshold, reaching 3 voxels ahead, gives 1.05-1.08.)
  const double area_ratio = mesh::surface_area_mm2(r.mesh) / torus_and_caps_mm2;
  EXPECT_GT(area_ratio, 0.97);
  EXPECT_LT(area_ratio, 1.05);
  EXPECT_NEAR(area_per_vertex_L2(r.mesh, p.vox_mm), 1.0, 0.2);
  EXPECT_EQ(self_near_seed_side, 0) << "self-intersection stops only where the fronts meet";
  EXPECT_EQ(self_on_outer_wall, 0);
  // Everything else rests on the wall.
  int boundary_far = 0;
  for (std::size_t i = 0; i < r.mesh.vertices.size(); ++i)
    if (r.stop[i] == StopReason::Boundary &&
        distance_to(wall, r.mesh.vertices[i]) > 1.5f * p.vox_mm)
      ++boundary_far;
  EXPECT_LE(boundary_far, static_cast<int>(r.mesh.vertices.size()) / 50);
}

TEST(Balloon, CystNeedleWrapsAroundTheNeedleWithoutLeaking) {
  const Prepared p = prepare("cyst-needle", 80);
  const auto r = segment::inflate_balloon(p.smoothed, p.phantom.seed_mm);
  ASSERT_EQ(r.error, "");
  EXPECT_TRUE(closed_and_consistently_oriented(r.mesh));
  EXPECT_EQ(segment::euler_characteristic(r.mesh), 2);
  EXPECT_GE(count(r, StopReason::SelfIntersection), 5) << "the sheets close behind the needle";

  const auto wall = truth_wall_mm(p.phantom.truth);
  // "Outside" means outside the cyst or inside the needle (the truth excludes the needle). The
  // wall samples are on the voxel staircase, hence half a voxel on top of the one-voxel bound.
  int outside_far = 0, checked_below_needle = 0;
  float worst_vox = 0.0f;
  const Vec3f centre = 0.5f * (p.phantom.image.min_mm() + p.phantom.image.max_mm());
  for (const auto& v : r.mesh.vertices) {
    if (inside_truth(p.phantom.truth, v)) continue;
    const float dist_vox = distance_to(wall, v) / p.vox_mm;
    worst_vox = std::max(worst_vox, dist_vox);
    if (dist_vox > 1.5f) ++outside_far;
  }
  // The deep half of the cyst lies in the needle's shadow (the needle enters from above).
  for (const auto& v : r.mesh.vertices)
    if (v.z() > centre.z() + 0.2f * (p.phantom.image.max_mm().z() - centre.z()))
      ++checked_below_needle;
  // Spec: within one voxel of the cyst everywhere, i.e. within 1.5 voxels of the staircase
  // samples. Measured over speckle seeds 1-6 at 64³, 80³ and 96³ (deterministic: the same
  // vertices on any thread count), with the rise summed per axis (BalloonOptions::rise_per_axis)
  // and the stops snapped to the wall (snap_to_wall): the spec holds in all 18 cases (worst 1.44).
  // With the paper's dot product it held in none at 80³ (worst 1.9-2.7), and the worst case was
  // 5.6 voxels out. (At 128³ it holds in 4 of 6: worst 1.26-2.32.) At 80³ this seed's worst is
  // 1.03, so asserted: the spec.
  EXPECT_EQ(outside_far, 0) << "worst " << worst_vox << " voxels outside the cyst";
  EXPECT_LE(worst_vox, 1.5f);
  EXPECT_GT(checked_below_needle, 50) << "the balloon reached the shadowed deep wall";
}

TEST(Balloon, RefusesASeedOnABrightStructureQuickly) {
  const Prepared p = prepare("cyst-needle", 64);
  // A seed in the tissue corner, well away from the cyst.
  const Vec3f tissue = p.phantom.image.index_to_mm(Vec3f(6, 6, 6));
  const auto t0 = std::chrono::steady_clock::now();
  const auto r = segment::inflate_balloon(p.smoothed, tissue);
  const double ms =
      std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count();
  EXPECT_NE(r.error, "");
  EXPECT_TRUE(r.mesh.vertices.empty());
  EXPECT_LT(ms, 2000.0) << "a refusal must not hang";  // generous: CI cores are shared
}

TEST(Balloon, RefusesASeedOnTheNeedle) {
  const Prepared p = prepare("cyst-needle", 64);
  // The brightest voxel of the smoothed image inside the cyst's bounding region is on the needle.
  const auto& s = p.smoothed.f32();
  std::size_t best = 0;
  for (std::size_t i = 0; i < s.size(); ++i)
    if (s[i] > s[best]) best = i;
  const Vec3i d = p.smoothed.dims();
  const Vec3f needle = p.smoothed.index_to_mm(
      Vec3f(static_cast<float>(best % d.x()), static_cast<float>((best / d.x()) % d.y()),
            static_cast<float>(best / (static_cast<std::size_t>(d.x()) * d.y()))));
  const auto r = segment::inflate_balloon(p.smoothed, needle);
  EXPECT_NE(r.error, "");
  EXPECT_NE(r.error.find("hypoechoic"), std::string::npos);
}

TEST(Balloon, ThrowsForASeedOutsideTheVolume) {
  const Prepared p = prepare("sphere", 48);
  EXPECT_THROW(segment::inflate_balloon(p.smoothed, p.phantom.image.max_mm() + Vec3f(5, 0, 0)),
               std::invalid_argument);
}

TEST(Balloon, HonoursTheStopToken) {
  const Prepared p = prepare("sphere", 48);
  std::stop_source source;
  source.request_stop();
  const auto r = segment::inflate_balloon(p.smoothed, p.phantom.seed_mm, {}, source.get_token());
  EXPECT_TRUE(r.stats.cancelled);
  EXPECT_FALSE(r.converged);
  EXPECT_EQ(segment::euler_characteristic(r.mesh), 2);  // still a valid (small) balloon
}

TEST(Balloon, RejectsAnInflationStepThatCouldJumpAWall) {
  const Prepared p = prepare("sphere", 48);
  EXPECT_THROW(segment::inflate_balloon(p.smoothed, p.phantom.seed_mm, {.inflation_vox = 0.9f}),
               std::invalid_argument);
}

TEST(Balloon, RejectsASnapWindowBeyondEightVoxels) {
  const Prepared p = prepare("sphere", 48);
  EXPECT_THROW(segment::inflate_balloon(p.smoothed, p.phantom.seed_mm,
                                        {.snap_back_vox = 4.0f, .snap_ahead_vox = 4.5f}),
               std::invalid_argument);
}

TEST(Balloon, SnapsStoppedVerticesOntoTheWallInsteadOfShortOfIt) {
  // Where Ψ_cost crosses τ_cost depends on the speckle it collected on the way: without the snap
  // the balloon rests inside the wall (64³, 11 speckle seeds: 0.33 voxel on average; this seed
  // 0.35, snapped 0.09).
  const Prepared p = prepare("sphere", 64);
  const Vec3f centre = 0.5f * (p.phantom.image.min_mm() + p.phantom.image.max_mm());
  auto mean_radius_mm = [&](const segment::BalloonResult& r) {
    double sum = 0.0;
    for (const auto& v : r.mesh.vertices) sum += (v - centre).norm();
    return static_cast<float>(sum / static_cast<double>(r.mesh.vertices.size()));
  };
  const auto snapped = segment::inflate_balloon(p.smoothed, p.phantom.seed_mm);
  const auto unsnapped =
      segment::inflate_balloon(p.smoothed, p.phantom.seed_mm, {.snap_to_wall = false});
  ASSERT_EQ(snapped.error, "");
  ASSERT_EQ(unsnapped.error, "");
  EXPECT_EQ(segment::euler_characteristic(snapped.mesh), 2);
  EXPECT_GT(mean_radius_mm(snapped) - mean_radius_mm(unsnapped), 0.1f * p.vox_mm)
      << "the snap moves the stopped balloon outwards, onto the wall";
}

TEST(Balloon, SerialAndParallelRunsAreIdentical) {
  // The cyst with its needle: the fronts meet behind the needle, so the self-intersection stops
  // depend on which front marked A_t first. Marks are applied in vertex order after each
  // parallel step, so the thread count must not change a single vertex.
  const Prepared p = prepare("cyst-needle", 56);
  const auto serial = segment::inflate_balloon(p.smoothed, p.phantom.seed_mm, {.threads = 1});
  const auto parallel = segment::inflate_balloon(p.smoothed, p.phantom.seed_mm, {.threads = 2});
  ASSERT_EQ(serial.error, "");
  EXPECT_GT(count(serial, StopReason::SelfIntersection), 0);
  EXPECT_EQ(serial.stats.iterations, parallel.stats.iterations);
  ASSERT_EQ(serial.mesh.vertices.size(), parallel.mesh.vertices.size());
  EXPECT_EQ(serial.mesh.triangles, parallel.mesh.triangles);
  EXPECT_EQ(serial.stop, parallel.stop);
  std::size_t differing = 0;
  for (std::size_t i = 0; i < serial.mesh.vertices.size(); ++i)
    differing += serial.mesh.vertices[i] != parallel.mesh.vertices[i];
  EXPECT_EQ(differing, 0u);
}

TEST(Balloon, ALeakThroughAGapIsSealedAtTheGap) {
  // A bright shell (radius 9-12 voxels) around a dark inside, with a hole 12 voxels wide on +x
  // into the dark outside: the balloon escapes through it and would fill the volume.
  volume::Volume image(Vec3i(48, 48, 48), Vec3f(1, 1, 1), Vec3f(0, 0, 0),
                       volume::VoxelType::Float32);
  for (int k = 0; k < 48; ++k)
    for (int j = 0; j < 48; ++j)
      for (int i = 0; i < 48; ++i) {
        const Vec3f d(i - 24.0f, j - 24.0f, k - 24.0f);
        const bool shell = d.norm() >= 9.0f && d.norm() <= 12.0f;
        const bool hole = d.x() > 0.0f && std::hypot(d.y(), d.z()) < 6.0f;
        image.f32()[image.linear_index(i, j, k)] = shell && !hole ? 120.0f : 30.0f;
      }
  const auto smoothed = volume::smooth_gaussian(image, 1.0f);
  // The default bound (the bounding box's whole area) would let it first spread over the volume
  // walls; a quarter of it is still four times this shell's area. The same bound as an area: the
  // box of 0-47 mm has 6 · 47² mm².
  for (const segment::BalloonOptions& options :
       {segment::BalloonOptions{.max_area_fraction = 0.25f},
        segment::BalloonOptions{.max_area_mm2 = 0.25f * 6.0f * 47.0f * 47.0f}}) {
    const auto r = segment::inflate_balloon(smoothed, Vec3f(24, 24, 24), options);
    // The balloon from before the leak inflated again with its vertices in the hole stopped: it
    // fills the shell's inside, its walls are the shell's, and what it sealed is the hole.
    ASSERT_TRUE(r.error.empty()) << r.error;
    EXPECT_GE(r.stats.leak_seals, 1);
    EXPECT_FALSE(r.stats.leaked);
    EXPECT_TRUE(r.converged);
    const double inside_ml = 4.0 / 3.0 * M_PI * std::pow(9.0, 3) / 1000.0;
    EXPECT_GT(mesh::enclosed_volume_ml(r.mesh), 0.5 * inside_ml);
    EXPECT_LT(mesh::enclosed_volume_ml(r.mesh), 1.5 * inside_ml);
    EXPECT_GT(r.stats.sealed_vertices, 0);
    int outside_shell = 0;
    for (const Vec3f& v : r.mesh.vertices) outside_shell += (v - Vec3f(24, 24, 24)).norm() > 12.0f;
    EXPECT_LE(outside_shell, static_cast<int>(r.mesh.vertices.size()) / 20);
  }
}

TEST(Balloon, WorksOnAnisotropicSpacing) {
  auto ph = sim::make_phantom(
      {.phantom = "sphere", .size_vox = 56, .spacing_mm = {0.5f, 0.5f, 0.8f}, .seed = 5});
  const auto sm = volume::smooth_gaussian(ph.image, 0.6f);
  const auto r = segment::inflate_balloon(sm, ph.seed_mm);
  ASSERT_EQ(r.error, "");
  const auto wall = truth_wall_mm(ph.truth);
  int far = 0;
  for (const auto& v : r.mesh.vertices) far += distance_to(wall, v) > 1.5f * 0.8f;  // coarsest axis
  EXPECT_LE(far, static_cast<int>(r.mesh.vertices.size()) / 50);
  EXPECT_EQ(segment::euler_characteristic(r.mesh), 2);
}

namespace {

// A closed torus (genus 1) about the z axis through `centre`: `rings` x `sides` quads, split.
segment::Mesh torus_mesh(const Vec3f& centre, float major_mm, float tube_mm, int rings = 96,
                         int sides = 32) {
  segment::Mesh m;
  for (int i = 0; i < rings; ++i)
    for (int j = 0; j < sides; ++j) {
      const float u = 2.0f * static_cast<float>(M_PI) * i / rings,
                  w = 2.0f * static_cast<float>(M_PI) * j / sides;
      const float r = major_mm + tube_mm * std::cos(w);
      m.vertices.push_back(centre + Vec3f(r * std::cos(u), r * std::sin(u), tube_mm * std::sin(w)));
    }
  auto at = [&](int i, int j) {
    return static_cast<std::uint32_t>((i % rings) * sides + (j % sides));
  };
  for (int i = 0; i < rings; ++i)
    for (int j = 0; j < sides; ++j) {  // counter-clockwise seen from outside
      m.triangles.push_back({at(i, j), at(i + 1, j), at(i + 1, j + 1)});
      m.triangles.push_back({at(i, j), at(i + 1, j + 1), at(i, j + 1)});
    }
  return m;
}

// Mean and worst distance of the vertices from the torus's true tube wall, in voxels.
std::pair<float, float> tube_wall_error_vox(const segment::Mesh& m, const Vec3f& centre,
                                            float major_mm, float tube_mm, float vox_mm) {
  double sum = 0.0;
  float worst = 0.0f;
  for (const auto& v : m.vertices) {
    const Vec3f q = v - centre;
    const float ring = std::hypot(q.x(), q.y()) - major_mm;
    const float e = std::abs(std::hypot(ring, q.z()) - tube_mm) / vox_mm;
    sum += e;
    worst = std::max(worst, e);
  }
  return {static_cast<float>(sum / m.vertices.size()), worst};
}

// The simulator's torus (sim/internal/shapes.cpp): axis z through the volume's centre, major
// radius 0.42 R and tube 0.2 R, R the half extent.
struct SimTorus {
  Vec3f centre;
  float major_mm, tube_mm;
  explicit SimTorus(const volume::Volume& image)
      : centre(0.5f * (image.min_mm() + image.max_mm())),
        major_mm(0.42f * 0.5f * (image.max_mm().x() - image.min_mm().x())),
        tube_mm(0.2f * 0.5f * (image.max_mm().x() - image.min_mm().x())) {}
};

}  // namespace

TEST(Reinflate, GivesAThinnedTorusBackItsWallAndKeepsItsGenus) {
  // What the reconstruction's smoothing does to a thin tube: the surface sits inside the wall.
  // The second pass must bring it back to the wall without changing the topology.
  const Prepared p = prepare("torus", 64);
  const auto first = segment::inflate_balloon(p.smoothed, p.phantom.seed_mm);
  ASSERT_EQ(first.error, "");
  const SimTorus t(p.phantom.image);
  const segment::Mesh thinned = torus_mesh(t.centre, t.major_mm, t.tube_mm - 1.0f * p.vox_mm);
  const auto before = tube_wall_error_vox(thinned, t.centre, t.major_mm, t.tube_mm, p.vox_mm);

  const auto second = segment::reinflate(p.smoothed, thinned, first.stats);
  ASSERT_EQ(second.mesh.vertices.size(), thinned.vertices.size());
  EXPECT_EQ(second.mesh.triangles, thinned.triangles)
      << "connectivity, and with it the genus, stays";
  EXPECT_EQ(segment::euler_characteristic(second.mesh), 0);
  const auto after = tube_wall_error_vox(second.mesh, t.centre, t.major_mm, t.tube_mm, p.vox_mm);
  EXPECT_NEAR(before.first, 1.0f, 0.05f);
  EXPECT_LT(after.first, 0.5f) << "mean distance to the wall, voxels";
  EXPECT_LT(after.second, 1.6f) << "no vertex moved further than the bound (1.5 voxels)";
  float moved_most_vox = 0.0f;
  for (std::size_t i = 0; i < thinned.vertices.size(); ++i)
    moved_most_vox =
        std::max(moved_most_vox, (second.mesh.vertices[i] - thinned.vertices[i]).norm() / p.vox_mm);
  EXPECT_LE(moved_most_vox, 1.5f + 0.31f);  // the bound, plus the last step that reached it
  EXPECT_GE(second.stats.stop_counts[static_cast<std::size_t>(StopReason::Boundary)],
            static_cast<int>(0.9 * second.mesh.vertices.size()))
      << "nearly all stop on the wall, not at the move bound";
}

TEST(Reinflate, LeavesASurfaceOnTheWallWhereItIs) {
  const Prepared p = prepare("torus", 64);
  const auto first = segment::inflate_balloon(p.smoothed, p.phantom.seed_mm);
  ASSERT_EQ(first.error, "");
  const SimTorus t(p.phantom.image);
  // Half a voxel outside the wall: already past the mid level, so nothing may move outwards.
  const segment::Mesh outside = torus_mesh(t.centre, t.major_mm, t.tube_mm + 0.5f * p.vox_mm);
  const auto second = segment::reinflate(p.smoothed, outside, first.stats);
  const auto before = tube_wall_error_vox(outside, t.centre, t.major_mm, t.tube_mm, p.vox_mm);
  const auto after = tube_wall_error_vox(second.mesh, t.centre, t.major_mm, t.tube_mm, p.vox_mm);
  EXPECT_LE(after.first, before.first + 0.1f);
}

TEST(Reinflate, RefusesAnOpenSurface) {
  const Prepared p = prepare("sphere", 48);
  const auto first = segment::inflate_balloon(p.smoothed, p.phantom.seed_mm);
  ASSERT_EQ(first.error, "");
  segment::Mesh open = first.mesh;
  open.triangles.pop_back();
  EXPECT_THROW(segment::reinflate(p.smoothed, open, first.stats), std::invalid_argument);
  EXPECT_THROW(segment::reinflate(p.smoothed, first.mesh, segment::BalloonStats{}),
               std::invalid_argument);
}
