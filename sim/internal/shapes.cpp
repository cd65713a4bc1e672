#include "sim/internal/shapes.h"

#include <algorithm>
#include <cmath>
#include <limits>
#include <stdexcept>

namespace sonomesh::sim::internal {
namespace {

constexpr float kPi = 3.14159265358979f;
constexpr float kBreathingPeriodS = 4.0f;
// Breathing: a few voxels of translation (relative to R, so ~2.5 voxels at 64^3) and a few
// percent of scale. Both vanish at t = 0 so time_s = 0 is the rest shape.
constexpr float kBreathingShift = 0.08f;  // of R
constexpr float kBreathingScale = 0.03f;

// Shape sizes, all relative to R (half extent). Chosen so the thin parts are >= 4-5 voxels at 64^3
// and every target plus its breathing excursion stays >= 0.15 R away from the volume border.
constexpr float kSphereRadius = 0.5f;
constexpr float kEllipsoidAxes[3] = {0.38f, 0.45f, 0.65f};  // u, v, w(major)
constexpr float kTorusMajor = 0.42f, kTorusTube = 0.2f;     // hole radius 0.22 R
constexpr float kDoubleMajor = 0.28f, kDoubleTube = 0.15f, kDoubleOffset = 0.32f;  // holes 0.13 R
constexpr float kCystAxes[3] = {0.42f, 0.36f, 0.5f};
constexpr float kNeedleOffset = 0.12f;  // needle axis passes this far from the cyst centre
constexpr float kNeedleTip = 0.62f;     // beyond the cyst in every direction (cyst <= 0.5 R)
// LV: an apical view's left ventricle, its long axis along the spec axis (the beam by default),
// apex towards the probe, the base cut by the valve plane. Trabeculae are longitudinal ridges
// reaching into the cavity: 9 around, ~1.6 voxels deep at 64^3, faded out towards apex and base
// so each cross-section stays star-shaped around the axis (genus 0 at any size).
constexpr float kLvAxes[3] = {0.36f, 0.33f, 0.7f};  // u, v, w (apex at -w)
constexpr float kLvValve = 0.5f;                    // valve plane at c = +0.5 R
constexpr float kLvValveThick = 0.07f;              // the valve echo's slab, beyond the plane
constexpr float kLvTrabDepth = 0.05f, kLvBulge = 0.025f;
constexpr int kLvTrabCount = 9;

float ellipsoid_sdf(const Vec3f& q, const Vec3f& r) {
  // Quilez's bound: exact sign, distance accurate near the surface, which is all we use.
  const float k0 = q.cwiseQuotient(r).norm();
  const float k1 = q.cwiseQuotient(r.cwiseProduct(r)).norm();
  if (k1 <= 0.0f) return -r.minCoeff();
  return k0 * (k0 - 1.0f) / k1;
}

float torus_sdf(float a, float b, float c, float major, float tube) {
  const float ring = std::sqrt(a * a + b * b) - major;
  return std::sqrt(ring * ring + c * c) - tube;
}

Vec3f unit_or_throw(const Vec3f& v, const char* field) {
  const float n = v.norm();
  if (!(n > 1e-6f) || !v.allFinite())
    throw std::invalid_argument(std::string("PhantomSpec.") + field + " must be a non-zero vector");
  return v / n;
}

}  // namespace

ShapeKind parse_shape_kind(const std::string& name) {
  if (name == "sphere") return ShapeKind::Sphere;
  if (name == "ellipsoid") return ShapeKind::Ellipsoid;
  if (name == "torus") return ShapeKind::Torus;
  if (name == "cyst-needle") return ShapeKind::CystNeedle;
  if (name == "double-torus") return ShapeKind::DoubleTorus;
  if (name == "lv") return ShapeKind::Lv;
  throw std::invalid_argument("PhantomSpec.phantom: unknown phantom '" + name +
                              "' (sphere, ellipsoid, torus, cyst-needle, double-torus, lv)");
}

int shape_genus(ShapeKind kind) {
  switch (kind) {
    case ShapeKind::Sphere:
    case ShapeKind::Ellipsoid:
    case ShapeKind::Lv:
      return 0;
    case ShapeKind::Torus:
    case ShapeKind::CystNeedle:
      return 1;
    case ShapeKind::DoubleTorus:
      return 2;
  }
  return 0;
}

Shape::Shape(const PhantomSpec& spec, const Vec3f& origin_mm)
    : kind_(parse_shape_kind(spec.phantom)) {
  const Vec3f half = spec.spacing_mm * (static_cast<float>(spec.size_vox - 1) * 0.5f);
  centre_mm_ = origin_mm + half;
  half_extent_mm_ = half.minCoeff();
  const float R = half_extent_mm_;

  const float phase = 2.0f * kPi * spec.time_s / kBreathingPeriodS;
  // Mostly along the beam, a little sideways: organs slide obliquely under a probe.
  const Vec3f shift_dir = Vec3f(0.4f, 0.25f, 1.0f).normalized();
  shift_mm_ = shift_dir * (kBreathingShift * R * std::sin(phase));
  scale_ = 1.0f + kBreathingScale * std::sin(phase);

  switch (kind_) {  // radius of a ball around the centre containing the rest shape, of R
    case ShapeKind::Sphere:
      bound_ = kSphereRadius;
      break;
    case ShapeKind::Ellipsoid:
      bound_ = kEllipsoidAxes[2];
      break;
    case ShapeKind::Torus:
      bound_ = kTorusMajor + kTorusTube;
      break;
    case ShapeKind::DoubleTorus:
      bound_ = kDoubleOffset + kDoubleMajor + kDoubleTube;
      break;
    case ShapeKind::CystNeedle:
      bound_ = kCystAxes[2];
      break;
    case ShapeKind::Lv:
      bound_ = kLvAxes[2] + kLvBulge;
      break;
  }
  w_ = unit_or_throw(spec.axis, "axis");
  const Vec3f helper = std::abs(w_.x()) < 0.9f ? Vec3f::UnitX() : Vec3f::UnitY();
  u_ = (helper - helper.dot(w_) * w_).normalized();
  v_ = w_.cross(u_);

  if (kind_ == ShapeKind::CystNeedle && spec.needle) {
    Needle n;
    n.direction = unit_or_throw(spec.needle_axis, "needle_axis");
    Vec3f side = n.direction.cross(w_);
    if (side.norm() < 1e-3f) side = u_;  // needle along the cyst axis: offset sideways anyway
    n.point_mm = side.normalized() * (kNeedleOffset * R);
    n.tip_t_mm = spec.needle_reach * kNeedleTip * R;
    // ~1.25 voxels at 64^3, scaled with the volume, never below 1.2 voxels so the tunnel the
    // needle cuts through the cyst stays face-connected in the voxelised truth.
    const float radius_vox = std::max(1.2f, 1.25f * static_cast<float>(spec.size_vox) / 64.0f);
    n.radius_mm = radius_vox * spec.spacing_mm.maxCoeff();
    needle_ = n;
  }
}

float Shape::rest_target_sdf(const Vec3f& q) const {
  const float R = half_extent_mm_;
  // Most of the volume is far from the target: there the distance to a ball containing the shape
  // is a valid lower bound, positive and well beyond the partial-volume edge, so the image and
  // truth come out exactly the same, at a fraction of the cost.
  const float r = q.norm();
  if (r > (bound_ + 0.1f) * R) return r - bound_ * R;
  const float a = q.dot(u_), b = q.dot(v_), c = q.dot(w_);
  switch (kind_) {
    case ShapeKind::Sphere:
      return q.norm() - kSphereRadius * R;
    case ShapeKind::Ellipsoid:
      return ellipsoid_sdf(Vec3f(a, b, c),
                           Vec3f(kEllipsoidAxes[0], kEllipsoidAxes[1], kEllipsoidAxes[2]) * R);
    case ShapeKind::Torus:
      return torus_sdf(a, b, c, kTorusMajor * R, kTorusTube * R);
    case ShapeKind::DoubleTorus: {
      const float d = kDoubleOffset * R;
      return std::min(torus_sdf(a + d, b, c, kDoubleMajor * R, kDoubleTube * R),
                      torus_sdf(a - d, b, c, kDoubleMajor * R, kDoubleTube * R));
    }
    case ShapeKind::CystNeedle: {
      const float cyst =
          ellipsoid_sdf(Vec3f(a, b, c), Vec3f(kCystAxes[0], kCystAxes[1], kCystAxes[2]) * R);
      return std::max(cyst, -rest_needle_sdf(q));  // the cyst minus the needle
    }
    case ShapeKind::Lv:
      return rest_lv_sdf(a, b, c);
  }
  return std::numeric_limits<float>::max();
}

float Shape::rest_lv_sdf(float a, float b, float c) const {
  const float R = half_extent_mm_;
  const float body = ellipsoid_sdf(Vec3f(a, b, c), Vec3f(kLvAxes[0], kLvAxes[1], kLvAxes[2]) * R);
  const float theta = std::atan2(b, a);
  const float h = c / R;  // -0.7 apex .. +0.5 valve
  // Fade: full depth over the mid cavity, none at the apex (h < -0.45) or the valve (h > 0.42).
  const float fade =
      std::clamp((h + 0.45f) / 0.25f, 0.0f, 1.0f) * std::clamp((0.42f - h) / 0.15f, 0.0f, 1.0f);
  const float ridge = 0.5f + 0.5f * std::sin(kLvTrabCount * theta + 2.5f * h);
  const float bulge = std::sin(2.0f * theta + 1.3f) * std::cos(3.0f * h);  // the uneven wall
  const float wall = body + R * (fade * kLvTrabDepth * ridge * ridge + kLvBulge * bulge);
  return std::max(wall, c - kLvValve * R);
}

float Shape::valve_sdf_mm(const Vec3f& p_mm) const {
  if (kind_ != ShapeKind::Lv) return std::numeric_limits<float>::max();
  const float R = half_extent_mm_;
  const Vec3f q = to_rest(p_mm);
  const float c = q.dot(w_);
  const float slab = std::abs(c - (kLvValve + 0.5f * kLvValveThick) * R) - 0.5f * kLvValveThick * R;
  // The valve ring reaches a little beyond the cavity wall, into the myocardium.
  const Vec3f ring_axes = Vec3f(kLvAxes[0], kLvAxes[1], kLvAxes[2]) * (1.2f * R);
  const float ring = ellipsoid_sdf(Vec3f(q.dot(u_), q.dot(v_), c), ring_axes);
  return scale_ * std::max(slab, ring);
}

float Shape::rest_needle_sdf(const Vec3f& q) const {
  if (!needle_) return std::numeric_limits<float>::max();
  const Vec3f rel = q - needle_->point_mm;
  const float t = std::min(rel.dot(needle_->direction), needle_->tip_t_mm);
  return (rel - t * needle_->direction).norm() - needle_->radius_mm;
}

float Shape::target_sdf_mm(const Vec3f& p_mm) const {
  return scale_ * rest_target_sdf(to_rest(p_mm));
}

void Shape::evaluate_mm(const Vec3f& p_mm, float& target_sdf_mm, float& needle_sdf_mm) const {
  const Vec3f q = to_rest(p_mm);
  if (!needle_) {
    target_sdf_mm = scale_ * rest_target_sdf(q);
    needle_sdf_mm = std::numeric_limits<float>::max();
    return;
  }
  // Cyst minus needle, as in rest_target_sdf, sharing the needle distance.
  const float needle = rest_needle_sdf(q);
  const float R = half_extent_mm_;
  const float r = q.norm();
  const float cyst = r > (bound_ + 0.1f) * R
                         ? r - bound_ * R  // far from the cyst: the bounding-ball distance will do
                         : ellipsoid_sdf(Vec3f(q.dot(u_), q.dot(v_), q.dot(w_)),
                                         Vec3f(kCystAxes[0], kCystAxes[1], kCystAxes[2]) * R);
  target_sdf_mm = scale_ * std::max(cyst, -needle);
  needle_sdf_mm = scale_ * needle;
}

bool Shape::needle_through() const {
  if (!needle_) return false;
  const Vec3f tip = needle_->point_mm + needle_->tip_t_mm * needle_->direction;
  const float R = half_extent_mm_;
  return needle_->tip_t_mm > 0.0f &&
         ellipsoid_sdf(Vec3f(tip.dot(u_), tip.dot(v_), tip.dot(w_)),
                       Vec3f(kCystAxes[0], kCystAxes[1], kCystAxes[2]) * R) > 0.0f;
}

float Shape::needle_sdf_mm(const Vec3f& p_mm) const {
  if (!needle_) return std::numeric_limits<float>::max();
  return scale_ * rest_needle_sdf(to_rest(p_mm));
}

std::optional<Needle> Shape::needle_at_time() const {
  if (!needle_) return std::nullopt;
  Needle n = *needle_;
  n.point_mm = centre_mm_ + shift_mm_ + scale_ * n.point_mm;
  n.tip_t_mm *= scale_;
  n.radius_mm *= scale_;
  return n;
}

}  // namespace sonomesh::sim::internal
