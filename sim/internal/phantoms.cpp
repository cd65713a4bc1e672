#include <Eigen/Geometry>
#include <algorithm>
#include <cmath>
#include <stdexcept>

#include "sim/internal/echo.h"
#include "sim/internal/edt.h"
#include "sim/internal/parallel.h"
#include "sim/internal/shapes.h"
#include "sim/internal/speckle.h"
#include "sim/sim.h"

namespace sonomesh::sim {
namespace {

using internal::Shape;

// Image model constants. Tissue sits at ~120 grey levels at mid depth: headroom for speckle peaks
// and a needle that saturates near 255.
constexpr float kTissueLevel = 120.0f;
constexpr float kNeedleEcho = 2.4f;         // needle brightness relative to tissue (saturates)
constexpr float kNeedleSpeckleKeep = 0.3f;  // a specular needle is less speckled than tissue
constexpr float kShadowFloor = 0.35f;  // scatter fills the shadow; the cyst stays visible in it

float smoothstep01(float x) {
  x = std::clamp(x, 0.0f, 1.0f);
  return x * x * (3.0f - 2.0f * x);
}

void validate(const PhantomSpec& spec) {
  auto bad = [](const std::string& what) { throw std::invalid_argument("PhantomSpec." + what); };
  if (spec.size_vox < 16)
    bad("size_vox must be at least 16 (got " + std::to_string(spec.size_vox) + ")");
  if (spec.size_vox > 512)
    bad("size_vox must be at most 512 (got " + std::to_string(spec.size_vox) + ")");
  if (!spec.spacing_mm.allFinite() || !(spec.spacing_mm.array() > 0.0f).all())
    bad("spacing_mm must be positive");
  if (!(spec.contrast >= 0.0f && spec.contrast <= 1.0f)) bad("contrast must be in [0, 1]");
  if (!(spec.speckle >= 0.0f && spec.speckle <= 1.0f)) bad("speckle must be in [0, 1]");
  if (!(spec.attenuation_db_per_cm >= 0.0f && spec.attenuation_db_per_cm <= 20.0f))
    bad("attenuation_db_per_cm must be in [0, 20]");
  if (!std::isfinite(spec.time_s)) bad("time_s must be finite");
  if (!(spec.needle_reach >= -1.0f && spec.needle_reach <= 1.0f))
    bad("needle_reach must be in [-1, 1]");
  if (spec.realism == Realism::Echo && !(spec.speckle_mm >= 0.1f && spec.speckle_mm <= 5.0f))
    bad("speckle_mm must be in [0.1, 5] mm");
}

// The deepest voxel of the target (largest distance to the background). The distance transform
// runs on every `stride`-th voxel (about 64 samples per axis): the seed only has to be well inside,
// and this keeps large volumes cheap. Ties go to the lowest index, so the choice is deterministic.
Vec3i deepest_voxel(const volume::Volume& truth) {
  const Vec3i dims = truth.dims();
  const int stride = std::max(1, dims.minCoeff() / 64);
  const Vec3i sub_dims = (dims - Vec3i::Ones()) / stride + Vec3i::Ones();
  volume::Volume sub(sub_dims, truth.spacing_mm() * static_cast<float>(stride), truth.origin_mm(),
                     volume::VoxelType::UInt8);
  for (int k = 0; k < sub_dims.z(); ++k)
    for (int j = 0; j < sub_dims.y(); ++j)
      for (int i = 0; i < sub_dims.x(); ++i)
        sub.u8()[sub.linear_index(i, j, k)] =
            truth.u8()[truth.linear_index(i * stride, j * stride, k * stride)];
  const std::vector<float> d2 = internal::squared_distance_inside_mm2(sub);
  std::size_t best = 0;
  float best_d2 = -1.0f;
  for (std::size_t t = 0; t < d2.size(); ++t)
    if (sub.u8()[t] && d2[t] > best_d2) {
      best_d2 = d2[t];
      best = t;
    }
  if (best_d2 < 0.0f)
    throw std::invalid_argument("PhantomSpec: the target has no voxel at this size/spacing");
  const int nx = sub_dims.x(), ny = sub_dims.y();
  return Vec3i(static_cast<int>(best % nx), static_cast<int>((best / nx) % ny),
               static_cast<int>(best / (static_cast<std::size_t>(nx) * ny))) *
         stride;
}

}  // namespace

const std::vector<std::string>& phantom_names() {
  static const std::vector<std::string> names{"sphere",      "ellipsoid",    "torus",
                                              "cyst-needle", "double-torus", "lv"};
  return names;
}

Realism parse_realism(const std::string& name) {
  if (name == "simple") return Realism::Simple;
  if (name == "echo") return Realism::Echo;
  throw std::invalid_argument("realism: unknown mode '" + name + "' (simple, echo)");
}

const char* to_string(Realism realism) { return realism == Realism::Echo ? "echo" : "simple"; }

volume::Mat3f oblique_direction() {
  const float ax = 30.0f * 3.14159265f / 180.0f, az = 20.0f * 3.14159265f / 180.0f;
  return (Eigen::AngleAxisf(az, Vec3f::UnitZ()) * Eigen::AngleAxisf(ax, Vec3f::UnitX()))
      .toRotationMatrix();
}

PhantomSpec with_echo_realism(PhantomSpec spec) {
  spec.realism = Realism::Echo;
  spec.speckle = 1.0f;
  spec.attenuation_db_per_cm = 3.0f;
  return spec;
}

namespace {

// The simple image model (see Realism::Simple); its bytes are fixed by the existing results.
void render_simple(const PhantomSpec& spec, const Shape& shape, Phantom& out) {
  const Vec3i dims = out.image.dims();
  const Vec3f origin_mm = out.image.origin_mm();
  const auto speckle = spec.speckle > 0.0f ? internal::speckle_field(spec.seed, dims) : nullptr;
  const int nx = dims.x(), ny = dims.y(), nz = dims.z();
  const std::size_t slice = static_cast<std::size_t>(nx) * ny;
  const Vec3f h = spec.spacing_mm;
  // Partial-volume edge: the echo ramps over about one voxel across the surface.
  const float edge_mm = 0.6f * h.minCoeff();
  // Round-trip attenuation in amplitude, renormalised so that mid depth sits at kTissueLevel.
  const float db_per_mm = spec.attenuation_db_per_cm / 10.0f;
  const float mid_depth_mm = 0.5f * h.z() * static_cast<float>(nz - 1);
  const float gain = kTissueLevel * std::pow(10.0f, db_per_mm * mid_depth_mm / 20.0f);
  const bool needle = shape.has_needle();
  // Needle absorption per mm of path so that crossing its diameter vertically leaves ~30%.
  const float needle_absorb_per_mm =
      needle ? 1.2f / (2.0f * shape.needle_at_time()->radius_mm) : 0.0f;

  auto& img = out.image.u8();
  auto& truth = out.truth.u8();
  std::vector<float> att(nz);
  for (int k = 0; k < nz; ++k)
    att[k] = gain * std::pow(10.0f, -db_per_mm * h.z() * static_cast<float>(k) / 20.0f);

  // Rows (fixed j) in parallel, each walked from the transducer down (k ascending), so the needle's
  // acoustic shadow can be accumulated per column in the same pass: everything deeper along +z
  // than the needle in that column is darker.
  internal::parallel_chunks(0, ny, [&](int j0, int j1) {
    std::vector<float> trans(nx);
    for (int j = j0; j < j1; ++j) {
      std::fill(trans.begin(), trans.end(), 1.0f);
      const float y_mm = origin_mm.y() + h.y() * static_cast<float>(j);
      for (int k = 0; k < nz; ++k) {
        const float z_mm = origin_mm.z() + h.z() * static_cast<float>(k);
        const std::size_t row =
            static_cast<std::size_t>(k) * slice + static_cast<std::size_t>(j) * nx;
        for (int i = 0; i < nx; ++i) {
          const std::size_t idx = row + i;
          const Vec3f p(origin_mm.x() + h.x() * static_cast<float>(i), y_mm, z_mm);
          float sdf, needle_sdf;
          shape.evaluate_mm(p, sdf, needle_sdf);
          truth[idx] = sdf < 0.0f ? 1 : 0;
          const float inside = smoothstep01(0.5f - sdf / (2.0f * edge_mm));
          float echo = 1.0f - spec.contrast * inside;
          float speckle_strength = spec.speckle;
          float shadow = 1.0f;
          if (needle) {
            const float wn = smoothstep01(0.5f - needle_sdf / (2.0f * edge_mm));
            echo = echo * (1.0f - wn) + kNeedleEcho * wn;
            speckle_strength *= 1.0f - (1.0f - kNeedleSpeckleKeep) * wn;
            shadow = std::max(trans[i], kShadowFloor);
            if (wn > 0.0f) trans[i] *= std::exp(-needle_absorb_per_mm * wn * h.z());
          }
          const float grain =
              speckle ? (1.0f - speckle_strength + speckle_strength * (*speckle)[idx]) : 1.0f;
          const float v = att[k] * echo * grain * shadow;
          img[idx] = static_cast<std::uint8_t>(std::min(v + 0.5f, 255.0f));  // v >= 0: rounds
        }
      }
    }
  });
}

}  // namespace

Phantom make_phantom(const PhantomSpec& spec) {
  validate(spec);
  const Vec3i dims = Vec3i::Constant(spec.size_vox);
  const Vec3f origin_mm = Vec3f::Zero();  // z = 0 is the transducer face: depth grows with k
  const Shape shape(spec, origin_mm);

  Phantom out;
  out.name = spec.phantom;
  // (A cyst without its needle, or with the needle's tip inside it, has no tunnel.)
  out.genus = shape.kind() == internal::ShapeKind::CystNeedle && !shape.needle_through()
                  ? 0
                  : internal::shape_genus(shape.kind());
  out.image = volume::Volume(dims, spec.spacing_mm, origin_mm, volume::VoxelType::UInt8);
  out.truth = volume::Volume(dims, spec.spacing_mm, origin_mm, volume::VoxelType::UInt8);
  if (spec.realism == Realism::Echo)
    internal::render_echo(spec, shape, out.image, out.truth);
  else
    render_simple(spec, shape, out);

  out.seed_index = deepest_voxel(out.truth);
  out.seed_mm = out.image.index_to_mm(out.seed_index.cast<float>());
  if (spec.oblique) {  // seed_mm stays in the grid frame, where the pipeline runs
    out.image.set_direction(oblique_direction());
    out.truth.set_direction(oblique_direction());
  }
  return out;
}

acquire::RawVolume to_raw(const volume::Volume& image, std::uint64_t sequence,
                          std::uint64_t timestamp_ns) {
  acquire::RawVolume raw;
  raw.sequence = sequence;
  raw.timestamp_ns = timestamp_ns;
  raw.dims = {image.dims().x(), image.dims().y(), image.dims().z()};
  raw.spacing_mm = {image.spacing_mm().x(), image.spacing_mm().y(), image.spacing_mm().z()};
  raw.origin_mm = {image.origin_mm().x(), image.origin_mm().y(), image.origin_mm().z()};
  for (int c = 0; c < 3; ++c)
    for (int a = 0; a < 3; ++a) raw.direction[3 * c + a] = image.direction()(a, c);
  switch (image.type()) {
    case volume::VoxelType::UInt8:
      raw.type = acquire::ProbeVoxelType::UInt8;
      raw.voxels = image.u8();
      break;
    case volume::VoxelType::UInt16: {
      raw.type = acquire::ProbeVoxelType::UInt16;
      const auto& src = image.u16();
      raw.voxels.resize(2 * src.size());
      for (std::size_t t = 0; t < src.size(); ++t) {  // the protocol is little endian
        raw.voxels[2 * t] = static_cast<std::uint8_t>(src[t] & 0xFF);
        raw.voxels[2 * t + 1] = static_cast<std::uint8_t>(src[t] >> 8);
      }
      break;
    }
    case volume::VoxelType::Float32:
      throw std::invalid_argument("to_raw: a probe delivers uint8 or uint16, not float32");
  }
  return raw;
}

}  // namespace sonomesh::sim
