#pragma once
// Analytic test shapes: oriented, area-weighted samples with exact normals, closed meshes, and
// signed-distance fields (positive inside, so marching_cubes at iso 0 traces the surface).

#include <Eigen/Geometry>
#include <cmath>

#include "reconstruct/reconstruct.h"

namespace sonomesh::reconstruct::test {

inline constexpr float kPi = 3.14159265358979f;

/// Fibonacci-spiral samples of a sphere; each carries an equal share of the area.
inline PointCloud sphere_samples(const Vec3f& centre, float radius, int n) {
  PointCloud pc;
  const float golden = kPi * (3.0f - std::sqrt(5.0f));
  for (int i = 0; i < n; ++i) {
    const float z = 1.0f - 2.0f * (i + 0.5f) / n;
    const float r = std::sqrt(1.0f - z * z);
    const Vec3f dir(r * std::cos(golden * i), r * std::sin(golden * i), z);
    pc.points.push_back(centre + radius * dir);
    pc.normals.push_back(dir);
    pc.area_mm2.push_back(4.0f * kPi * radius * radius / n);
  }
  return pc;
}

/// Torus around the z axis: major radius R, minor radius r, nu × nv parameter grid.
inline PointCloud torus_samples(const Vec3f& centre, float R, float r, int nu, int nv) {
  PointCloud pc;
  for (int i = 0; i < nu; ++i)
    for (int j = 0; j < nv; ++j) {
      const float u = 2 * kPi * (i + 0.5f) / nu, v = 2 * kPi * (j + 0.5f) / nv;
      const Vec3f n(std::cos(v) * std::cos(u), std::cos(v) * std::sin(u), std::sin(v));
      const Vec3f ring(R * std::cos(u), R * std::sin(u), 0.0f);
      pc.points.push_back(centre + ring + r * n);
      pc.normals.push_back(n);
      pc.area_mm2.push_back((R + r * std::cos(v)) * r * (2 * kPi / nu) * (2 * kPi / nv));
    }
  return pc;
}

inline float torus_distance(const Vec3f& p, const Vec3f& centre, float R, float r) {
  const Vec3f q = p - centre;
  const float ring = std::hypot(q.x(), q.y()) - R;
  return std::abs(std::hypot(ring, q.z()) - r);
}

/// UV sphere (closed, outward, genus 0): `segments` around, `bands` latitude bands.
inline Mesh uv_sphere(const Vec3f& centre, float radius, int segments, int bands) {
  Mesh m;
  m.vertices.push_back(centre + Vec3f(0, 0, radius));
  for (int b = 1; b < bands; ++b) {
    const float th = kPi * b / bands;
    for (int s = 0; s < segments; ++s) {
      const float ph = 2 * kPi * s / segments;
      m.vertices.push_back(centre + radius * Vec3f(std::sin(th) * std::cos(ph),
                                                   std::sin(th) * std::sin(ph), std::cos(th)));
    }
  }
  m.vertices.push_back(centre + Vec3f(0, 0, -radius));
  const auto south = static_cast<std::uint32_t>(m.vertices.size() - 1);
  auto ring = [&](int b, int s) {
    return static_cast<std::uint32_t>(1 + (b - 1) * segments + (s % segments));
  };
  for (int s = 0; s < segments; ++s) m.triangles.push_back({0, ring(1, s), ring(1, s + 1)});
  for (int b = 1; b + 1 < bands; ++b)
    for (int s = 0; s < segments; ++s) {
      m.triangles.push_back({ring(b, s), ring(b + 1, s), ring(b + 1, s + 1)});
      m.triangles.push_back({ring(b, s), ring(b + 1, s + 1), ring(b, s + 1)});
    }
  for (int s = 0; s < segments; ++s)
    m.triangles.push_back({south, ring(bands - 1, s + 1), ring(bands - 1, s)});
  return m;
}

/// Float32 field on an n³ grid (spacing h, origin o) from f(p_mm).
template <class F>
volume::Volume field(int n, float h, const Vec3f& origin, F&& f) {
  volume::Volume v(volume::Vec3i(n, n, n), Vec3f::Constant(h), origin, volume::VoxelType::Float32);
  auto& d = v.f32();
  for (int k = 0; k < n; ++k)
    for (int j = 0; j < n; ++j)
      for (int i = 0; i < n; ++i) d[v.linear_index(i, j, k)] = f(v.index_to_mm(Vec3f(i, j, k)));
  return v;
}

}  // namespace sonomesh::reconstruct::test
