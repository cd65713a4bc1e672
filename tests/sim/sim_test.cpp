#include "sim/sim.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <nlohmann/json.hpp>
#include <sstream>
#include <stdexcept>
#include <string>

#include "sim/internal/shapes.h"
#include "sim/internal/speckle.h"
#include "topology.h"

namespace sonomesh::sim {
namespace {

using testing::solid_topology;

PhantomSpec spec_for(const std::string& name, int size, std::uint32_t seed = 1) {
  PhantomSpec s;
  s.phantom = name;
  s.size_vox = size;
  s.seed = seed;
  return s;
}

double mean_where(const volume::Volume& image, const std::vector<std::uint8_t>& mask) {
  double sum = 0.0;
  std::size_t n = 0;
  for (std::size_t t = 0; t < mask.size(); ++t)
    if (mask[t]) {
      sum += image.u8()[t];
      ++n;
    }
  return n ? sum / static_cast<double>(n) : std::nan("");
}

// --- Topology of the ground truth -------------------------------------------------------------

struct TopologyCase {
  std::string phantom;
  int size;
  Vec3f axis;
  float time_s;
};

void PrintTo(const TopologyCase& c, std::ostream* os) {
  *os << c.phantom << " size " << c.size << " axis " << c.axis.transpose() << " t " << c.time_s;
}

class SimTruthTopology : public ::testing::TestWithParam<TopologyCase> {};

TEST_P(SimTruthTopology, HasTheStatedGenus) {
  const auto& c = GetParam();
  PhantomSpec spec = spec_for(c.phantom, c.size);
  spec.axis = c.axis;
  spec.time_s = c.time_s;
  spec.speckle = 0.0f;  // topology only; skip the speckle field
  const Phantom p = make_phantom(spec);
  const auto topo = solid_topology(p.truth);
  EXPECT_EQ(topo.components, 1);
  EXPECT_EQ(topo.cavities, 0);
  EXPECT_EQ(topo.tunnels(), p.genus) << "euler " << topo.euler;
}

// The needle switched off (withdrawn): the cyst alone, genus 0, and the image differs only
// around where the needle and its shadow were.
TEST(SimTopology, CystWithoutItsNeedleHasGenusZero) {
  PhantomSpec spec = spec_for("cyst-needle", 64);
  spec.needle = false;
  const Phantom without = make_phantom(spec);
  EXPECT_EQ(without.genus, 0);
  const auto topo = solid_topology(without.truth);
  EXPECT_EQ(topo.components, 1);
  EXPECT_EQ(topo.tunnels(), 0);
  spec.needle = true;
  const Phantom with = make_phantom(spec);
  EXPECT_EQ(with.genus, 1);
  std::size_t differ = 0;
  for (std::size_t i = 0; i < with.image.u8().size(); ++i)
    differ += with.image.u8()[i] != without.image.u8()[i];
  EXPECT_GT(differ, 0u);
  EXPECT_LT(differ, with.image.u8().size() / 4);
}

// The needle withdrawn half-way (its tip in the cyst's middle): a dent, genus 0 in the truth
// too, and the cyst's voxels between those of the cyst pierced and of the cyst alone.
TEST(SimTopology, NeedleWithdrawnHalfWayLeavesADent) {
  PhantomSpec spec = spec_for("cyst-needle", 64);
  const auto inside = [](const Phantom& p) {
    return std::count_if(p.truth.u8().begin(), p.truth.u8().end(), [](auto v) { return v; });
  };
  spec.needle_reach = 0.0f;
  const Phantom half = make_phantom(spec);
  EXPECT_EQ(half.genus, 0);
  const auto topo = solid_topology(half.truth);
  EXPECT_EQ(topo.components, 1);
  EXPECT_EQ(topo.cavities, 0);
  EXPECT_EQ(topo.tunnels(), 0);
  spec.needle_reach = 1.0f;
  const auto through = inside(make_phantom(spec));
  spec.needle = false;
  const auto alone = inside(make_phantom(spec));
  EXPECT_GT(inside(half), through);
  EXPECT_LT(inside(half), alone);
  spec.needle = true;
  spec.needle_reach = 1.5f;
  EXPECT_THROW(make_phantom(spec), std::invalid_argument);
}

INSTANTIATE_TEST_SUITE_P(Phantoms, SimTruthTopology,
                         ::testing::Values(TopologyCase{"sphere", 48, Vec3f::UnitZ(), 0.0f},
                                           TopologyCase{"ellipsoid", 64, Vec3f(1, 1, 0), 0.0f},
                                           TopologyCase{"torus", 48, Vec3f::UnitZ(), 0.0f},
                                           TopologyCase{"torus", 64, Vec3f(1, 2, 3), 1.0f},
                                           TopologyCase{"cyst-needle", 48, Vec3f::UnitZ(), 0.0f},
                                           TopologyCase{"cyst-needle", 64, Vec3f::UnitZ(), 1.0f},
                                           TopologyCase{"cyst-needle", 96, Vec3f(0, 1, 1), 0.0f},
                                           TopologyCase{"double-torus", 48, Vec3f::UnitZ(), 3.0f},
                                           TopologyCase{"double-torus", 64, Vec3f::UnitZ(), 0.0f},
                                           TopologyCase{"double-torus", 64, Vec3f(1, 0, 1), 0.0f}),
                         [](const auto& info) {
                           std::string name = info.param.phantom + "_" +
                                              std::to_string(info.param.size) + "_" +
                                              std::to_string(info.index);
                           for (char& ch : name)
                             if (ch == '-') ch = '_';
                           return name;
                         });

TEST(SimTopology, GenusFieldMatchesNames) {
  EXPECT_EQ(phantom_names().size(), 6u);
  const std::pair<const char*, int> expected[] = {
      {"sphere", 0}, {"ellipsoid", 0}, {"torus", 1}, {"cyst-needle", 1}, {"double-torus", 2}};
  for (const auto& [name, genus] : expected) {
    PhantomSpec s = spec_for(name, 32);
    s.speckle = 0.0f;
    EXPECT_EQ(make_phantom(s).genus, genus) << name;
  }
}

TEST(SimTopology, EulerCharacteristicOfKnownSolids) {
  // The checker itself: a solid block (chi 1) and a block with a square tunnel (chi 0).
  volume::Volume v(Vec3i(8, 8, 8), Vec3f::Ones(), Vec3f::Zero(), volume::VoxelType::UInt8);
  for (int k = 2; k < 6; ++k)
    for (int j = 1; j < 7; ++j)
      for (int i = 1; i < 7; ++i) v.u8()[v.linear_index(i, j, k)] = 1;
  auto topo = solid_topology(v);
  EXPECT_EQ(topo.euler, 1);
  EXPECT_EQ(topo.tunnels(), 0);
  for (int k = 2; k < 6; ++k) v.u8()[v.linear_index(3, 3, k)] = 0;
  topo = solid_topology(v);
  EXPECT_EQ(topo.euler, 0);
  EXPECT_EQ(topo.tunnels(), 1);
  EXPECT_EQ(topo.cavities, 0);
}

// --- Seed point ---------------------------------------------------------------------------------

TEST(SimSeed, IsDeepInsideTheTarget) {
  for (const auto& name : phantom_names()) {
    PhantomSpec s = spec_for(name, 64);
    s.speckle = 0.0f;
    const Phantom p = make_phantom(s);
    ASSERT_TRUE(p.truth.contains_index(p.seed_index)) << name;
    EXPECT_TRUE(p.seed_mm.isApprox(p.truth.index_to_mm(p.seed_index.cast<float>()))) << name;
    // Every voxel within 3 voxels of the seed is target (so it is also away from the needle).
    const int r = 3;
    for (int dk = -r; dk <= r; ++dk)
      for (int dj = -r; dj <= r; ++dj)
        for (int di = -r; di <= r; ++di) {
          if (di * di + dj * dj + dk * dk > r * r) continue;
          const Vec3i q = p.seed_index + Vec3i(di, dj, dk);
          ASSERT_EQ(p.truth.u8()[p.truth.linear_index(q.x(), q.y(), q.z())], 1)
              << name << " seed " << p.seed_index.transpose() << " offset " << di << ',' << dj
              << ',' << dk;
        }
  }
}

TEST(SimSeed, CystNeedleSeedIsAwayFromTheNeedle) {
  const PhantomSpec s = spec_for("cyst-needle", 64);
  const Phantom p = make_phantom(s);
  const internal::Shape shape(s, p.image.origin_mm());
  const float vox = s.spacing_mm.x();
  EXPECT_GT(shape.needle_sdf_mm(p.seed_mm), 3.0f * vox);
  EXPECT_LT(shape.target_sdf_mm(p.seed_mm), -3.0f * vox);
}

// --- Determinism ---------------------------------------------------------------------------------

TEST(SimDeterminism, SameSeedSameBytesOtherSeedOtherBytes) {
  const Phantom a = make_phantom(spec_for("cyst-needle", 48, 7));
  const Phantom b = make_phantom(spec_for("cyst-needle", 48, 8));
  const Phantom c = make_phantom(spec_for("cyst-needle", 48, 7));  // after the cache moved on
  EXPECT_EQ(a.image.u8(), c.image.u8());
  EXPECT_EQ(a.truth.u8(), c.truth.u8());
  EXPECT_EQ(a.seed_index, c.seed_index);
  EXPECT_NE(a.image.u8(), b.image.u8());
  EXPECT_EQ(a.truth.u8(), b.truth.u8());  // the seed changes speckle, not geometry
}

TEST(SimSpeckle, GaussianGeneratorIsStandardNormal) {
  internal::GaussianPairs g(99);
  double sum = 0, sum2 = 0, cross = 0;
  const int n = 200000;
  for (int t = 0; t < n; ++t) {
    float a, b;
    g.next(a, b);
    sum += a + b;
    sum2 += a * a + b * b;
    cross += a * b;
  }
  EXPECT_NEAR(sum / (2 * n), 0.0, 0.01);
  EXPECT_NEAR(sum2 / (2 * n), 1.0, 0.01);
  EXPECT_NEAR(cross / n, 0.0, 0.01);
}

TEST(SimSpeckle, FieldIsUnitMeanRayleighAndLongerLaterally) {
  const Vec3i dims(48, 48, 48);
  const auto field = internal::speckle_field(11, dims);
  ASSERT_EQ(field->size(), 48u * 48u * 48u);
  double sum = 0, sum2 = 0;
  for (float v : *field) sum += v, sum2 += double(v) * v;
  const double mean = sum / field->size();
  const double sd = std::sqrt(sum2 / field->size() - mean * mean);
  EXPECT_NEAR(mean, 1.0, 0.03);
  EXPECT_NEAR(sd / mean, 0.523, 0.04);  // Rayleigh: sqrt(4 / pi - 1)
  auto lag1 = [&](std::size_t stride) {
    double c = 0;
    std::size_t n = 0;
    for (std::size_t t = 0; t + stride < field->size(); t += 7, ++n)
      c += ((*field)[t] - mean) * ((*field)[t + stride] - mean);
    return c / n / (sd * sd);
  };
  const double cx = lag1(1), cz = lag1(48 * 48);
  EXPECT_GT(cx, cz + 0.1) << "lateral " << cx << " axial " << cz;
  EXPECT_GT(cz, 0.1);
}

// --- Image model ---------------------------------------------------------------------------------

struct Regions {
  std::vector<std::uint8_t> target, tissue;
};

// Target: at least 2 voxels inside; tissue: a shell 3..8 voxels outside (same depths).
Regions regions(const PhantomSpec& spec, const Phantom& p) {
  const internal::Shape shape(spec, p.image.origin_mm());
  const float vox = spec.spacing_mm.x();
  Regions r{std::vector<std::uint8_t>(p.image.voxel_count()),
            std::vector<std::uint8_t>(p.image.voxel_count())};
  const Vec3i d = p.image.dims();
  for (int k = 0; k < d.z(); ++k)
    for (int j = 0; j < d.y(); ++j)
      for (int i = 0; i < d.x(); ++i) {
        const float sdf = shape.target_sdf_mm(p.image.index_to_mm(Vec3f(i, j, k))) / vox;
        r.target[p.image.linear_index(i, j, k)] = sdf < -2.0f;
        r.tissue[p.image.linear_index(i, j, k)] = sdf > 3.0f && sdf < 8.0f;
      }
  return r;
}

TEST(SimImageModel, TargetIsDarkerThanTissueByTheContrast) {
  for (float contrast : {0.7f, 0.4f}) {
    PhantomSpec s = spec_for("sphere", 64);
    s.contrast = contrast;
    const Phantom p = make_phantom(s);
    const Regions r = regions(s, p);
    const double target = mean_where(p.image, r.target), tissue = mean_where(p.image, r.tissue);
    EXPECT_GT(tissue, 100.0);
    EXPECT_LT(tissue, 135.0);
    EXPECT_NEAR(target / tissue, 1.0 - contrast, 0.05) << "contrast " << contrast;
  }
}

// Separable Gaussian, sigma in voxels, clamped borders (the test's own, independent of volume/).
std::vector<float> smooth(const volume::Volume& v, float sigma) {
  const int rad = static_cast<int>(std::ceil(3 * sigma));
  std::vector<float> w(2 * rad + 1);
  float sum = 0;
  for (int t = -rad; t <= rad; ++t) sum += w[t + rad] = std::exp(-0.5f * t * t / (sigma * sigma));
  for (float& x : w) x /= sum;
  std::vector<float> a = v.to_float(), b(a.size());
  const Vec3i d = v.dims();
  for (int axis = 0; axis < 3; ++axis) {
    for (int k = 0; k < d.z(); ++k)
      for (int j = 0; j < d.y(); ++j)
        for (int i = 0; i < d.x(); ++i) {
          float acc = 0;
          for (int t = -rad; t <= rad; ++t) {
            Vec3i q(i, j, k);
            q[axis] = std::clamp(q[axis] + t, 0, d[axis] - 1);
            acc += w[t + rad] * a[v.linear_index(q.x(), q.y(), q.z())];
          }
          b[v.linear_index(i, j, k)] = acc;
        }
    std::swap(a, b);
  }
  return a;
}

TEST(SimImageModel, BoundaryIsClearAfterOneVoxelSmoothing) {
  const PhantomSpec s = spec_for("torus", 64);
  const Phantom p = make_phantom(s);
  const std::vector<float> sm = smooth(p.image, 1.0f);
  const internal::Shape shape(s, p.image.origin_mm());
  const float vox = s.spacing_mm.x();
  const Regions r = regions(s, p);
  double in_sum = 0, out_sum = 0;
  std::size_t in_n = 0, out_n = 0;
  for (std::size_t t = 0; t < sm.size(); ++t) {
    if (r.target[t]) in_sum += sm[t], ++in_n;
    if (r.tissue[t]) out_sum += sm[t], ++out_n;
  }
  const double threshold = 0.5 * (in_sum / in_n + out_sum / out_n);
  // Voxels 2..6 voxels from the surface on either side: a midpoint threshold classifies them.
  std::size_t wrong = 0, total = 0;
  const Vec3i d = p.image.dims();
  for (int k = 0; k < d.z(); ++k)
    for (int j = 0; j < d.y(); ++j)
      for (int i = 0; i < d.x(); ++i) {
        const float sdf = shape.target_sdf_mm(p.image.index_to_mm(Vec3f(i, j, k))) / vox;
        if (std::abs(sdf) < 2.0f || std::abs(sdf) > 6.0f) continue;
        ++total;
        const bool dark = sm[p.image.linear_index(i, j, k)] < threshold;
        wrong += dark != (sdf < 0.0f);
      }
  ASSERT_GT(total, 1000u);
  EXPECT_LT(static_cast<double>(wrong) / total, 0.02) << wrong << " of " << total;
}

TEST(SimImageModel, AttenuationDarkensWithDepth) {
  PhantomSpec s = spec_for("sphere", 64);
  s.attenuation_db_per_cm = 4.0f;  // 3.2 cm deep: 12.8 dB round trip, a factor ~4.4 in amplitude
  const Phantom p = make_phantom(s);
  const Vec3i d = p.image.dims();
  auto slab_mean = [&](int k0, int k1) {
    double sum = 0;
    std::size_t n = 0;
    for (int k = k0; k < k1; ++k)
      for (int j = 0; j < 8; ++j)  // a corner column, far from the sphere
        for (int i = 0; i < 8; ++i) sum += p.image.u8()[p.image.linear_index(i, j, k)], ++n;
    return sum / n;
  };
  const double top = slab_mean(0, 6), bottom = slab_mean(d.z() - 6, d.z());
  EXPECT_GT(top / bottom, 3.0);
  EXPECT_LT(top / bottom, 6.0);
}

TEST(SimImageModel, NeedleIsBrightAndCastsAShadow) {
  const PhantomSpec s = spec_for("cyst-needle", 64);
  const Phantom p = make_phantom(s);
  const internal::Shape shape(s, p.image.origin_mm());
  const auto needle = shape.needle_at_time();
  ASSERT_TRUE(needle.has_value());
  const float vox = s.spacing_mm.x();
  const float R = shape.half_extent_mm();

  // Bright: voxels inside the needle, outside the cyst.
  std::vector<std::uint8_t> in_needle(p.image.voxel_count());
  const Vec3i d = p.image.dims();
  for (int k = 0; k < d.z(); ++k)
    for (int j = 0; j < d.y(); ++j)
      for (int i = 0; i < d.x(); ++i) {
        const Vec3f x = p.image.index_to_mm(Vec3f(i, j, k));
        in_needle[p.image.linear_index(i, j, k)] =
            shape.needle_sdf_mm(x) < -0.3f * vox && shape.target_sdf_mm(x) > 2.0f * vox;
      }
  EXPECT_GT(mean_where(p.image, in_needle), 180.0);  // tissue is ~120

  // Shadow: tissue 3..8 voxels below the needle shaft (outside the cyst) against tissue at the same
  // depths 10 voxels to the side (off the needle's vertical plane).
  double below = 0, beside = 0;
  int n = 0;
  for (float t = -0.9f * R; t < -0.5f * R; t += vox) {
    const Vec3f axis_pt = needle->point_mm + t * needle->direction;
    for (float dz = 3; dz <= 8; dz += 1) {
      const Vec3f a = axis_pt + Vec3f(0, 0, (needle->radius_mm / vox + dz) * vox);
      const Vec3f b = a + Vec3f(0, 10.0f * vox, 0);
      if (!p.image.contains_mm(a) || !p.image.contains_mm(b)) continue;
      if (shape.target_sdf_mm(a) < 2 * vox || shape.target_sdf_mm(b) < 2 * vox) continue;
      if (shape.needle_sdf_mm(a) < 2 * vox) continue;
      const Vec3i ia = p.image.mm_to_index(a).array().round().cast<int>();
      const Vec3i ib = p.image.mm_to_index(b).array().round().cast<int>();
      below += p.image.u8()[p.image.linear_index(ia.x(), ia.y(), ia.z())];
      beside += p.image.u8()[p.image.linear_index(ib.x(), ib.y(), ib.z())];
      ++n;
    }
  }
  ASSERT_GT(n, 30);
  EXPECT_LT(below / n, 0.5 * beside / n) << "below " << below / n << " beside " << beside / n;
}

TEST(SimImageModel, SpeckleZeroGivesAFlatTissue) {
  PhantomSpec s = spec_for("sphere", 48);
  s.speckle = 0.0f;
  s.attenuation_db_per_cm = 0.0f;
  const Phantom p = make_phantom(s);
  EXPECT_EQ(p.image.u8()[0], 120);
  EXPECT_EQ(p.image.u8()[p.image.voxel_count() - 1], 120);
  EXPECT_EQ(
      p.image.u8()[p.image.linear_index(p.seed_index.x(), p.seed_index.y(), p.seed_index.z())], 36);
}

// --- Breathing -----------------------------------------------------------------------------------

Vec3f centroid(const volume::Volume& truth) {
  Eigen::Vector3d sum = Eigen::Vector3d::Zero();
  double n = 0;
  const Vec3i d = truth.dims();
  for (int k = 0; k < d.z(); ++k)
    for (int j = 0; j < d.y(); ++j)
      for (int i = 0; i < d.x(); ++i)
        if (truth.u8()[truth.linear_index(i, j, k)]) sum += Eigen::Vector3d(i, j, k), n += 1;
  return (sum / n).cast<float>();
}

TEST(SimBreathing, TimeMovesTheTargetAndAPeriodBringsItBack) {
  PhantomSpec s = spec_for("ellipsoid", 64);
  s.speckle = 0.0f;
  const Phantom rest = make_phantom(s);
  s.time_s = 1.0f;  // quarter period: largest excursion
  const Phantom moved = make_phantom(s);
  s.time_s = 4.0f;  // one period
  const Phantom back = make_phantom(s);
  const float shift_vox = (centroid(moved.truth) - centroid(rest.truth)).norm();
  EXPECT_GT(shift_vox, 1.5f);
  EXPECT_LT(shift_vox, 5.0f);
  EXPECT_LT((centroid(back.truth) - centroid(rest.truth)).norm(), 0.1f);
  EXPECT_TRUE(moved.truth.u8()[moved.truth.linear_index(moved.seed_index.x(), moved.seed_index.y(),
                                                        moved.seed_index.z())]);
}

TEST(SimBreathing, EveryPhantomStaysClearOfTheBorderAtItsExtremes) {
  for (const auto& name : phantom_names())
    for (float t : {1.0f, 3.0f})
      for (const Vec3f& axis : {Vec3f(0, 0, 1), Vec3f(1, 1, 1)}) {
        PhantomSpec s = spec_for(name, 48);
        s.speckle = 0.0f;
        s.time_s = t;
        s.axis = axis;
        const Phantom p = make_phantom(s);
        const Vec3i d = p.truth.dims();
        const int margin = 3;
        std::size_t touching = 0;
        for (int k = 0; k < d.z(); ++k)
          for (int j = 0; j < d.y(); ++j)
            for (int i = 0; i < d.x(); ++i) {
              const bool border = i < margin || j < margin || k < margin || i >= d.x() - margin ||
                                  j >= d.y() - margin || k >= d.z() - margin;
              if (border) touching += p.truth.u8()[p.truth.linear_index(i, j, k)];
            }
        EXPECT_EQ(touching, 0u) << name << " t " << t << " axis " << axis.transpose();
      }
}

TEST(SimTopology, AnisotropicSpacingKeepsTheGenus) {
  for (const std::string name : {"torus", "cyst-needle", "double-torus"}) {
    PhantomSpec s = spec_for(name, 64);
    s.spacing_mm = Vec3f(0.4f, 0.4f, 0.6f);
    s.speckle = 0.0f;
    const Phantom p = make_phantom(s);
    const auto topo = solid_topology(p.truth);
    EXPECT_EQ(topo.components, 1) << name;
    EXPECT_EQ(topo.cavities, 0) << name;
    EXPECT_EQ(topo.tunnels(), p.genus) << name;
  }
}

// --- Errors and probe records --------------------------------------------------------------------

TEST(SimErrors, BadSpecsThrowNamingTheField) {
  auto message = [](const PhantomSpec& s) {
    try {
      make_phantom(s);
    } catch (const std::invalid_argument& e) {
      return std::string(e.what());
    }
    return std::string("no throw");
  };
  EXPECT_NE(message(spec_for("cube", 32)).find("phantom"), std::string::npos);
  EXPECT_NE(message(spec_for("sphere", 8)).find("size_vox"), std::string::npos);
  PhantomSpec s = spec_for("torus", 32);
  s.axis = Vec3f::Zero();
  EXPECT_NE(message(s).find("axis"), std::string::npos);
  s = spec_for("sphere", 32);
  s.contrast = 1.5f;
  EXPECT_NE(message(s).find("contrast"), std::string::npos);
}

TEST(SimToRaw, CarriesGridAndBytes) {
  const Phantom p = make_phantom(spec_for("sphere", 32));
  const acquire::RawVolume raw = to_raw(p.image, 42, 1234);
  EXPECT_EQ(raw.sequence, 42u);
  EXPECT_EQ(raw.timestamp_ns, 1234u);
  EXPECT_EQ(raw.dims, (std::array<int, 3>{32, 32, 32}));
  EXPECT_EQ(raw.type, acquire::ProbeVoxelType::UInt8);
  EXPECT_EQ(raw.spacing_mm[2], p.image.spacing_mm().z());
  EXPECT_EQ(raw.voxels, p.image.u8());
  const volume::Volume back = volume::Volume::from_raw(raw);
  EXPECT_EQ(back.u8(), p.image.u8());
  EXPECT_TRUE(back.origin_mm().isApprox(p.image.origin_mm()));
}

// --- probe-sim generate ------------------------------------------------------------------------

struct CommandResult {
  int status;
  std::string err;
};

CommandResult run(const std::string& args, const std::filesystem::path& dir) {
  const auto err_path = dir / "stderr.txt";
  const std::string cmd =
      std::string(PROBE_SIM_EXE) + " " + args + " 2>" + err_path.string() + " >/dev/null";
  const int status = std::system(cmd.c_str());
  std::ifstream f(err_path);
  std::stringstream ss;
  ss << f.rdbuf();
  return {status, ss.str()};
}

class ProbeSimCli : public ::testing::Test {
 protected:
  void SetUp() override {
    dir_ = std::filesystem::temp_directory_path() /
           ("sim_tests_" + std::to_string(::testing::UnitTest::GetInstance()->random_seed()) + "_" +
            ::testing::UnitTest::GetInstance()->current_test_info()->name());
    std::filesystem::create_directories(dir_);
  }
  void TearDown() override { std::filesystem::remove_all(dir_); }
  std::filesystem::path dir_;
};

TEST_F(ProbeSimCli, GenerateWritesVolumeTruthAndSidecar) {
  const auto vol = dir_ / "torus.nrrd", truth = dir_ / "torus_truth.mha";
  const auto r = run("generate --phantom torus --size 48 --seed 5 --spacing 0.4 --out " +
                         vol.string() + " --truth " + truth.string(),
                     dir_);
  ASSERT_EQ(r.status, 0) << r.err;
  ASSERT_TRUE(std::filesystem::exists(vol));
  ASSERT_TRUE(std::filesystem::exists(truth));
  std::ifstream js(dir_ / "torus.json");
  ASSERT_TRUE(js.good());
  const auto j = nlohmann::json::parse(js);
  EXPECT_EQ(j.at("phantom"), "torus");
  EXPECT_EQ(j.at("genus"), 1);
  EXPECT_EQ(j.at("size"), 48);
  EXPECT_EQ(j.at("seed"), 5);
  EXPECT_FLOAT_EQ(j.at("spacing_mm")[1].get<float>(), 0.4f);
  ASSERT_EQ(j.at("seed_index").size(), 3u);
  ASSERT_EQ(j.at("seed_mm").size(), 3u);

  // The files hold what make_phantom makes.
  PhantomSpec s = spec_for("torus", 48, 5);
  s.spacing_mm = Vec3f::Constant(0.4f);
  const Phantom p = make_phantom(s);
  EXPECT_EQ(j.at("seed_index")[0].get<int>(), p.seed_index.x());
  EXPECT_NEAR(j.at("seed_mm")[2].get<float>(), p.seed_mm.z(), 1e-4);
  const auto image_back = volume::read_volume(vol);
  ASSERT_TRUE(image_back) << image_back.error->message;
  EXPECT_EQ(image_back.volume.u8(), p.image.u8());
  const auto truth_back = volume::read_volume(truth);
  ASSERT_TRUE(truth_back) << truth_back.error->message;
  EXPECT_EQ(truth_back.volume.u8(), p.truth.u8());
  EXPECT_TRUE(truth_back.volume.spacing_mm().isApprox(Vec3f::Constant(0.4f)));
}

TEST_F(ProbeSimCli, GenerateEchoUsesThePresetUnlessTold) {
  const auto vol = dir_ / "lv.nrrd", truth = dir_ / "lv_truth.nrrd";
  const auto r =
      run("generate --phantom lv --size 48 --realism echo --contrast 0.4 --speckle-mm 0.8 --out " +
              vol.string() + " --truth " + truth.string(),
          dir_);
  ASSERT_EQ(r.status, 0) << r.err;
  std::ifstream js(dir_ / "lv.json");
  const auto j = nlohmann::json::parse(js);
  EXPECT_EQ(j.at("realism"), "echo");
  EXPECT_FLOAT_EQ(j.at("speckle").get<float>(), 1.0f);
  EXPECT_FLOAT_EQ(j.at("attenuation_db_per_cm").get<float>(), 3.0f);
  EXPECT_FLOAT_EQ(j.at("speckle_mm").get<float>(), 0.8f);
  PhantomSpec s = spec_for("lv", 48);
  s.contrast = 0.4f;
  s = with_echo_realism(s);
  s.speckle_mm = 0.8f;
  const auto back = volume::read_volume(vol);
  ASSERT_TRUE(back) << back.error->message;
  EXPECT_EQ(back.volume.u8(), make_phantom(s).image.u8());
  // An explicit --speckle wins over the preset.
  const auto r2 = run("generate --phantom lv --size 48 --realism echo --speckle 0.5 --out " +
                          vol.string() + " --truth " + truth.string(),
                      dir_);
  ASSERT_EQ(r2.status, 0) << r2.err;
  std::ifstream js2(dir_ / "lv.json");
  EXPECT_FLOAT_EQ(nlohmann::json::parse(js2).at("speckle").get<float>(), 0.5f);
}

TEST_F(ProbeSimCli, BadArgumentsGiveOneLineAndNonZeroExit) {
  const std::string files =
      " --out " + (dir_ / "a.nrrd").string() + " --truth " + (dir_ / "b.nrrd").string();
  for (const std::string& args :
       {std::string("generate --phantom cube") + files,
        std::string("generate --phantom sphere --size 4") + files,
        std::string("generate --phantom sphere --spacing 1,2") + files,
        std::string("generate --phantom sphere --out x.png --truth y.nrrd"),
        std::string("generate"), std::string("generate --phantom lv --realism photo") + files,
        std::string("generate --phantom lv --realism echo --speckle-mm 0") + files,
        std::string("bogus")}) {
    const auto r = run(args, dir_);
    EXPECT_NE(r.status, 0) << args;
    EXPECT_FALSE(r.err.empty()) << args;
    EXPECT_EQ(std::count(r.err.begin(), r.err.end(), '\n'), 1) << args << ": " << r.err;
  }
  EXPECT_FALSE(std::filesystem::exists(dir_ / "a.nrrd"));
}

}  // namespace
}  // namespace sonomesh::sim
