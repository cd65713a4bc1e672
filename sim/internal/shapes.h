#pragma once
/// @file
/// @brief Implicit phantom geometry: target signed distance and needle distance, in mm.
///
/// Every size is relative to the half extent of the volume (R), so a phantom looks the same at
/// 48^3 and 256^3. The breathing motion (translation + scale, period 4 s) is folded into the
/// evaluation, so callers just ask "how far is this point from the target at time t".

#include <Eigen/Core>
#include <Eigen/Geometry>
#include <optional>
#include <string>

#include "sim/sim.h"

namespace sonomesh::sim::internal {

enum class ShapeKind { Sphere, Ellipsoid, Torus, CystNeedle, DoubleTorus, Lv };

/// Parses a phantom name. @throws std::invalid_argument for an unknown name.
ShapeKind parse_shape_kind(const std::string& name);
int shape_genus(ShapeKind kind);

/// A needle: a cylinder around a half-line ending at the tip (entry outside the volume).
struct Needle {
  Vec3f point_mm;      // a point on the axis, inside the cyst (rest pose, volume frame)
  Vec3f direction;     // unit, from entry towards the tip
  float tip_t_mm = 0;  // the tip is point_mm + direction * tip_t_mm
  float radius_mm = 0;
};

class Shape {
 public:
  /// Geometry for a spec on its grid (origin_mm is the volume origin, index 0).
  /// @throws std::invalid_argument for an unknown phantom or a zero axis.
  Shape(const PhantomSpec& spec, const Vec3f& origin_mm);

  ShapeKind kind() const { return kind_; }
  /// Signed distance to the target surface in mm (negative inside; exact for sphere and tori,
  /// a close bound for ellipsoids), at the spec's time.
  float target_sdf_mm(const Vec3f& p_mm) const;
  bool has_needle() const { return needle_.has_value(); }
  /// Whether the needle goes through the target and out (cyst-needle: its tip outside the cyst).
  bool needle_through() const;
  /// Distance to the needle surface in mm (negative inside the needle); FLT_MAX if no needle.
  float needle_sdf_mm(const Vec3f& p_mm) const;
  /// Both distances at once (the per-voxel hot path: the breathing transform is undone once).
  void evaluate_mm(const Vec3f& p_mm, float& target_sdf_mm, float& needle_sdf_mm) const;
  /// LV only: signed distance in mm to the valve plane's echo, a slab closing the cavity's base
  /// (negative inside it); FLT_MAX for other phantoms.
  float valve_sdf_mm(const Vec3f& p_mm) const;
  /// The needle at the spec's time (moved and scaled with the target).
  std::optional<Needle> needle_at_time() const;
  /// Centre of the volume in mm and the half extent R in mm.
  const Vec3f& centre_mm() const { return centre_mm_; }
  float half_extent_mm() const { return half_extent_mm_; }

 private:
  // Point in the rest frame (relative to the centre, breathing undone).
  Vec3f to_rest(const Vec3f& p_mm) const { return (p_mm - centre_mm_ - shift_mm_) / scale_; }
  float rest_target_sdf(const Vec3f& q) const;
  float rest_needle_sdf(const Vec3f& q) const;
  float rest_lv_sdf(float a, float b, float c) const;

  ShapeKind kind_;
  Vec3f centre_mm_;
  float half_extent_mm_;
  Vec3f shift_mm_;   // breathing translation at spec.time_s
  float scale_;      // breathing scale at spec.time_s
  float bound_ = 1;  // the rest target lies within this radius (of R) around the centre
  Vec3f u_, v_, w_;  // local frame, w = spec.axis
  std::optional<Needle> needle_;  // rest pose, relative to the centre
};

}  // namespace sonomesh::sim::internal
