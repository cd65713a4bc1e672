#pragma once
/// @file
/// @brief The echo realism mode: a phantom's image as a 3D echo probe would show it.

#include "sim/internal/shapes.h"
#include "sim/sim.h"

namespace sonomesh::sim::internal {

/// The probe's field of view: a pyramid from an apex centred above the volume's top face (z = 0),
/// the beam fanning out along +z, cut off at a maximum range (the sector's bottom arc). Sized so
/// that every phantom (default axis) lies inside it with a margin of >= 0.1 R at any breathing
/// time.
class Sector {
 public:
  Sector(const PhantomSpec& spec, const Vec3f& origin_mm);
  /// Distance in mm from p to the sector's boundary: positive inside, <= 0 outside.
  float inside_mm(const Vec3f& p_mm) const;
  /// Range from the apex in mm (the depth along the beam through p).
  float range_mm(const Vec3f& p_mm) const { return (p_mm - apex_mm_).norm(); }
  const Vec3f& apex_mm() const { return apex_mm_; }
  /// Range of the volume's top face below the apex, where the near field begins.
  float top_range_mm() const { return top_range_mm_; }

 private:
  Vec3f apex_mm_;
  float tan_half_ = 0, cos_half_ = 0;
  float max_range_mm_ = 0, top_range_mm_ = 0;
};

/// Renders the echo image and the truth labels (sdf < 0, exactly as the simple mode) of a spec.
/// Both volumes must already have the spec's grid. Deterministic in the spec.
void render_echo(const PhantomSpec& spec, const Shape& shape, volume::Volume& image,
                 volume::Volume& truth);

}  // namespace sonomesh::sim::internal
