#include "sim/internal/echo.h"

#include <algorithm>
#include <cmath>

#include "sim/internal/parallel.h"
#include "sim/internal/speckle.h"

namespace sonomesh::sim::internal {
namespace {

// Sector: apex 0.3 R above the top face, 40 degree half-angle both ways, bottom arc at 2.25 R.
constexpr float kApexAbove = 0.3f, kHalfAngleDeg = 40.0f, kMaxRange = 2.25f;
// Grey level of tissue at the volume centre's range, after time-gain compensation. Fully developed
// speckle peaks at ~3x its mean; the specular walls, valve and needle saturate.
constexpr float kTissueLevel = 90.0f;
constexpr float kTgcCompensation = 0.8f;  // TGC undoes 80 % of the attenuation: deep is darker
constexpr float kNoise = 0.04f;           // electronic noise at mid range, of tissue; TGC lifts it
constexpr float kClutter = 0.7f;          // near-field clutter at the top face, of tissue
constexpr float kClutterDecay = 0.3f;     // ... falling by e every 0.3 R of range
constexpr float kSpecular = 0.8f;         // wall echo where the beam meets the wall head-on
constexpr float kDropout = 0.8f;          // tissue echo lost next to a wall parallel to the beam
constexpr float kMyocardium = 1.35f, kMyocardiumWall = 0.12f;  // LV: brighter muscle, of R
constexpr float kValveEcho = 1.9f;
constexpr float kNeedleEcho = 2.4f, kNeedleSpeckleKeep = 0.3f, kShadowFloor = 0.35f;

float smoothstep01(float x) {
  x = std::clamp(x, 0.0f, 1.0f);
  return x * x * (3.0f - 2.0f * x);
}

// Distance between segments [p0, p1] and [q0, q1] (Ericson, Real-Time Collision Detection 5.1.9).
float segment_distance(const Vec3f& p0, const Vec3f& p1, const Vec3f& q0, const Vec3f& q1) {
  const Vec3f d1 = p1 - p0, d2 = q1 - q0, r = p0 - q0;
  const float a = d1.squaredNorm(), e = d2.squaredNorm(), f = d2.dot(r);
  const float c = d1.dot(r), b = d1.dot(d2), denom = a * e - b * b;
  float s = denom > 1e-12f ? std::clamp((b * f - c * e) / denom, 0.0f, 1.0f) : 0.0f;
  float t = (b * s + f) / e;
  if (t < 0.0f) {
    t = 0.0f;
    s = std::clamp(-c / a, 0.0f, 1.0f);
  } else if (t > 1.0f) {
    t = 1.0f;
    s = std::clamp((b - c) / a, 0.0f, 1.0f);
  }
  return (p0 + d1 * s - (q0 + d2 * t)).norm();
}

// Per-volume constants of the image model.
struct Model {
  const PhantomSpec& spec;
  const Shape& shape;
  Sector sector;
  float edge_mm;       // partial-volume ramp across a surface
  float band_mm;       // walls: the specular echo and dropout act within this of the surface
  float db_per_mm;     // round-trip attenuation
  float mid_range_mm;  // range of the volume centre: the TGC's reference
  float R;
  bool lv;
  std::optional<Needle> needle;
  Vec3f needle_entry_mm = Vec3f::Zero(), needle_tip_mm = Vec3f::Zero();
};

// Unit normal of the target surface at p (central differences of the signed distance).
Vec3f surface_normal(const Shape& shape, const Vec3f& p, float step_mm) {
  Vec3f g;
  for (int a = 0; a < 3; ++a) {
    Vec3f d = Vec3f::Zero();
    d[a] = step_mm;
    g[a] = shape.target_sdf_mm(p + d) - shape.target_sdf_mm(p - d);
  }
  const float n = g.norm();
  return n > 0.0f ? Vec3f(g / n) : Vec3f::UnitZ();
}

// Reflectivity of the scatterers at p, before speckle, attenuation and shadow (tissue = 1).
// speckle_keep returns how much of the speckle a specular needle keeps.
float reflectivity(const Model& m, const Vec3f& p, float sdf, float needle_sdf,
                   float& speckle_keep) {
  float tissue = 1.0f;
  if (m.lv) {
    const float muscle = smoothstep01(0.5f + (kMyocardiumWall * m.R - sdf) / (2.0f * m.edge_mm));
    tissue += (kMyocardium - 1.0f) * muscle;
    const float valve = smoothstep01(0.5f - m.shape.valve_sdf_mm(p) / (2.0f * m.edge_mm));
    tissue += (kValveEcho - tissue) * valve;
  }
  const float blood = 1.0f - m.spec.contrast;
  if (std::abs(sdf) < m.band_mm) {
    const Vec3f beam = (p - m.sector.apex_mm()).normalized();
    const float facing = std::abs(surface_normal(m.shape, p, m.edge_mm).dot(beam));
    if (sdf > 0.0f) {  // the tissue side: dropout where the wall runs along the beam
      const float along = std::pow(1.0f - facing, 3.0f) * (1.0f - sdf / m.band_mm);
      tissue = blood + (tissue - blood) * (1.0f - kDropout * along);
    }
    const float wall = (sdf - 0.5f * m.edge_mm) / m.edge_mm;
    tissue += kSpecular * facing * facing * std::exp(-0.5f * wall * wall);
  }
  const float inside = smoothstep01(0.5f - sdf / (2.0f * m.edge_mm));
  float echo = tissue + (blood - tissue) * inside;
  speckle_keep = 1.0f;
  if (m.needle) {
    const float wn = smoothstep01(0.5f - needle_sdf / (2.0f * m.edge_mm));
    echo += (kNeedleEcho - echo) * wn;
    speckle_keep = 1.0f - (1.0f - kNeedleSpeckleKeep) * wn;
  }
  return echo;
}

// The needle's acoustic shadow: the beam from the apex to p crosses the needle on its way.
float shadow(const Model& m, const Vec3f& p, float needle_sdf) {
  if (!m.needle || needle_sdf <= 0.0f) return 1.0f;
  const float d = segment_distance(m.sector.apex_mm(), p, m.needle_entry_mm, m.needle_tip_mm);
  const float hidden = smoothstep01(0.5f + (m.needle->radius_mm - d) / m.edge_mm);
  return 1.0f - (1.0f - kShadowFloor) * hidden;
}

void render_row(const Model& m, int j, int k, const std::vector<float>& speckle,
                volume::Volume& image, volume::Volume& truth) {
  const Vec3i dims = image.dims();
  const Vec3f h = m.spec.spacing_mm, o = image.origin_mm();
  const std::size_t row = image.linear_index(0, j, k);
  // Clutter and noise are independent of the tissue speckle: the same field read mirrored.
  const std::size_t mirror_row = image.linear_index(0, dims.y() - 1 - j, dims.z() - 1 - k);
  const float s = m.spec.speckle;
  for (int i = 0; i < dims.x(); ++i) {
    const Vec3f p = o + h.cwiseProduct(Vec3f(static_cast<float>(i), static_cast<float>(j),
                                             static_cast<float>(k)));
    float sdf, needle_sdf;
    m.shape.evaluate_mm(p, sdf, needle_sdf);
    truth.u8()[row + i] = sdf < 0.0f ? 1 : 0;
    const float in_sector = m.sector.inside_mm(p);
    if (in_sector <= 0.0f) {
      image.u8()[row + i] = 0;
      continue;
    }
    float keep;
    const float echo = reflectivity(m, p, sdf, needle_sdf, keep);
    const float grain = 1.0f - s * keep + s * keep * speckle[row + i];
    const float other = speckle[mirror_row + (dims.x() - 1 - i)];
    const float r = m.sector.range_mm(p);
    const float net_gain =
        std::pow(10.0f, -(1.0f - kTgcCompensation) * m.db_per_mm * (r - m.mid_range_mm) / 20.0f);
    const float tgc =
        std::pow(10.0f, kTgcCompensation * m.db_per_mm * (r - m.mid_range_mm) / 20.0f);
    const float clutter =
        kClutter * std::exp(-(r - m.sector.top_range_mm()) / (kClutterDecay * m.R));
    const float v =
        net_gain * echo * grain * shadow(m, p, needle_sdf) + (clutter + kNoise * tgc) * other;
    const float taper = smoothstep01(in_sector / h.minCoeff());  // the sector's edge, ~1 voxel
    // Inside the sector a probe never shows exact 0: zero marks "outside the field of view".
    image.u8()[row + i] =
        static_cast<std::uint8_t>(std::clamp(kTissueLevel * v * taper + 0.5f, 1.0f, 255.0f));
  }
}

}  // namespace

Sector::Sector(const PhantomSpec& spec, const Vec3f& origin_mm) {
  const Vec3f half = spec.spacing_mm * (static_cast<float>(spec.size_vox - 1) * 0.5f);
  const float R = half.minCoeff();
  apex_mm_ = origin_mm + Vec3f(half.x(), half.y(), -kApexAbove * R);
  const float angle = kHalfAngleDeg * 3.14159265f / 180.0f;
  tan_half_ = std::tan(angle);
  cos_half_ = std::cos(angle);
  top_range_mm_ = kApexAbove * R;
  max_range_mm_ = kMaxRange * R;
}

float Sector::inside_mm(const Vec3f& p_mm) const {
  const Vec3f d = p_mm - apex_mm_;
  if (d.z() <= 0.0f) return -1.0f;
  // Distance to each side plane of the pyramid, and to the bottom arc.
  const float side_x = (tan_half_ * d.z() - std::abs(d.x())) * cos_half_;
  const float side_y = (tan_half_ * d.z() - std::abs(d.y())) * cos_half_;
  return std::min({side_x, side_y, max_range_mm_ - d.norm()});
}

void render_echo(const PhantomSpec& spec, const Shape& shape, volume::Volume& image,
                 volume::Volume& truth) {
  const Vec3f h = spec.spacing_mm;
  const Vec3f sigma_vox(spec.speckle_mm / h.x(), spec.speckle_mm / h.y(),
                        0.5f * spec.speckle_mm / h.z());
  const auto speckle = speckle_field(spec.seed, image.dims(), sigma_vox);
  Model m{spec,
          shape,
          Sector(spec, image.origin_mm()),
          0.6f * h.minCoeff(),
          2.5f * h.maxCoeff(),
          spec.attenuation_db_per_cm / 10.0f,
          0.0f,
          shape.half_extent_mm(),
          shape.kind() == ShapeKind::Lv,
          shape.needle_at_time()};
  m.mid_range_mm = m.sector.range_mm(shape.centre_mm());
  if (m.needle) {  // the needle enters from far outside the volume
    m.needle_tip_mm = m.needle->point_mm + m.needle->direction * m.needle->tip_t_mm;
    m.needle_entry_mm = m.needle->point_mm - m.needle->direction * (4.0f * m.R);
  }
  const int ny = image.dims().y(), nz = image.dims().z();
  parallel_chunks(0, nz, [&](int k0, int k1) {
    for (int k = k0; k < k1; ++k)
      for (int j = 0; j < ny; ++j) render_row(m, j, k, *speckle, image, truth);
  });
}

}  // namespace sonomesh::sim::internal
