// The echo realism mode: sector, blood pool, clutter, dropout, TGC, speckle grain; truth as before.
#include <gtest/gtest.h>

#include <cmath>
#include <string>

#include "sim/internal/echo.h"
#include "sim/internal/shapes.h"
#include "sim/phantom_source.h"
#include "sim/sim.h"
#include "topology.h"

namespace sonomesh::sim {
namespace {

using testing::solid_topology;

PhantomSpec echo_spec(const std::string& name, int size, float contrast = 0.7f,
                      std::uint32_t seed = 1) {
  PhantomSpec s;
  s.phantom = name;
  s.size_vox = size;
  s.seed = seed;
  s.contrast = contrast;
  return with_echo_realism(s);
}

Vec3f voxel_mm(const volume::Volume& v, int i, int j, int k) {
  return v.index_to_mm(Vec3f(static_cast<float>(i), static_cast<float>(j), static_cast<float>(k)));
}

// Calls f(linear index, sdf in voxels, in-sector distance in voxels, position) for every voxel.
template <class F>
void for_each_voxel(const PhantomSpec& spec, const Phantom& p, const F& f) {
  const internal::Shape shape(spec, p.image.origin_mm());
  const internal::Sector sector(spec, p.image.origin_mm());
  const float vox = spec.spacing_mm.minCoeff();
  const Vec3i d = p.image.dims();
  for (int k = 0; k < d.z(); ++k)
    for (int j = 0; j < d.y(); ++j)
      for (int i = 0; i < d.x(); ++i) {
        const Vec3f x = voxel_mm(p.image, i, j, k);
        f(p.image.linear_index(i, j, k), shape.target_sdf_mm(x) / vox, sector.inside_mm(x) / vox,
          x);
      }
}

struct Means {
  double cavity = 0, tissue = 0, cavity_cv = 0;
};

// Cavity: >= 2 voxels inside the target; tissue: 3..8 voxels outside it; both inside the sector.
Means cavity_and_tissue(const PhantomSpec& spec, const Phantom& p) {
  double cs = 0, cs2 = 0, ts = 0;
  std::size_t cn = 0, tn = 0;
  for_each_voxel(spec, p, [&](std::size_t t, float sdf, float sector, const Vec3f&) {
    if (sector <= 1.0f) return;
    const double v = p.image.u8()[t];
    if (sdf < -2.0f) cs += v, cs2 += v * v, ++cn;
    if (sdf > 3.0f && sdf < 8.0f) ts += v, ++tn;
  });
  Means m;
  m.cavity = cs / static_cast<double>(cn);
  m.tissue = ts / static_cast<double>(tn);
  m.cavity_cv = std::sqrt(cs2 / static_cast<double>(cn) - m.cavity * m.cavity) / m.cavity;
  return m;
}

const char* kEchoPhantoms[] = {"lv", "cyst-needle", "torus", "double-torus"};

TEST(SimEcho, ZerosOutsideTheSectorAndNoneInsideIt) {
  for (const char* name : kEchoPhantoms) {
    const PhantomSpec spec = echo_spec(name, 64);
    const Phantom p = make_phantom(spec);
    std::size_t outside = 0, outside_nonzero = 0, inside_zero = 0, truth_near_edge = 0;
    for_each_voxel(spec, p, [&](std::size_t t, float, float sector, const Vec3f&) {
      if (sector <= 0.0f) {
        ++outside;
        outside_nonzero += p.image.u8()[t] != 0;
      } else {
        inside_zero += p.image.u8()[t] == 0;
      }
      if (p.truth.u8()[t] && sector < 2.0f) ++truth_near_edge;
    });
    const double fraction =
        static_cast<double>(outside) / static_cast<double>(p.image.voxel_count());
    EXPECT_GT(fraction, 0.15) << name;  // a fan, not a cube
    EXPECT_LT(fraction, 0.6) << name;
    EXPECT_EQ(outside_nonzero, 0u) << name;
    EXPECT_EQ(inside_zero, 0u) << name;
    EXPECT_EQ(truth_near_edge, 0u) << name << ": the target must lie well inside the sector";
    for (float t : {1.0f, 3.0f}) {  // at the breathing extremes too
      PhantomSpec moved = spec;
      moved.time_s = t;
      moved.speckle = 0.0f;
      const Phantom q = make_phantom(moved);
      std::size_t near_edge = 0;
      for_each_voxel(moved, q, [&](std::size_t i, float, float sector, const Vec3f&) {
        near_edge += q.truth.u8()[i] && sector < 2.0f;
      });
      EXPECT_EQ(near_edge, 0u) << name << " t " << t;
    }
  }
}

TEST(SimEcho, BloodPoolIsSpeckledAtTenToFortyPercentOfTissue) {
  for (const char* name : kEchoPhantoms) {
    const PhantomSpec spec = echo_spec(name, 64, 0.7f);
    const Means m = cavity_and_tissue(spec, make_phantom(spec));
    const double ratio = m.cavity / m.tissue;
    EXPECT_GT(ratio, 0.10) << name;
    EXPECT_LT(ratio, 0.40) << name;
    EXPECT_GT(m.cavity, 10.0) << name << ": not black";
    EXPECT_GT(m.cavity_cv, 0.35) << name << ": fully developed speckle in the blood pool";
  }
}

TEST(SimEcho, ContrastSetsTheCavityToTissueRatio) {
  for (float contrast : {0.3f, 0.5f}) {
    const PhantomSpec spec = echo_spec("torus", 64, contrast);
    const Means m = cavity_and_tissue(spec, make_phantom(spec));
    EXPECT_NEAR(m.cavity / m.tissue, 1.0 - contrast, 0.08) << contrast;
  }
}

TEST(SimEcho, TruthIsTheSimpleModesTruthWithItsGenus) {
  for (const char* name : {"lv", "cyst-needle", "torus", "double-torus", "sphere"})
    for (float t : {0.0f, 1.0f}) {
      PhantomSpec simple;
      simple.phantom = name;
      simple.size_vox = 64;
      simple.time_s = t;
      PhantomSpec echo = with_echo_realism(simple);
      const Phantom a = make_phantom(simple), b = make_phantom(echo);
      EXPECT_EQ(a.truth.u8(), b.truth.u8()) << name;
      EXPECT_EQ(a.seed_index, b.seed_index) << name;
      const auto topo = solid_topology(b.truth);
      EXPECT_EQ(topo.components, 1) << name;
      EXPECT_EQ(topo.cavities, 0) << name;
      EXPECT_EQ(topo.tunnels(), b.genus) << name;
    }
}

TEST(SimEcho, LvCavityIsGenusZeroAtEverySizeAndAxis) {
  for (int size : {48, 96})
    for (const auto& [axis, t] :
         {std::pair{Vec3f(0, 0, 1), 0.0f}, std::pair{Vec3f(0, 0, 1), 3.0f},
          std::pair{Vec3f(1, 0, 2), 1.0f}, std::pair{Vec3f(1, 1, 1), 0.0f}}) {
      PhantomSpec s;
      s.phantom = "lv";
      s.size_vox = size;
      s.axis = axis;
      s.time_s = t;
      s.speckle = 0.0f;
      const Phantom p = make_phantom(s);
      const auto topo = solid_topology(p.truth);
      EXPECT_EQ(p.genus, 0);
      EXPECT_EQ(topo.components, 1) << size << " t " << t;
      EXPECT_EQ(topo.cavities, 0) << size << " t " << t;
      EXPECT_EQ(topo.tunnels(), 0) << size << " axis " << axis.transpose() << " t " << t;
    }
}

TEST(SimEcho, LvHasAnUnevenWallAndABrightValvePlane) {
  const PhantomSpec spec = echo_spec("lv", 96, 0.6f);
  const Phantom p = make_phantom(spec);
  const internal::Shape shape(spec, p.image.origin_mm());
  // Trabeculae: around the mid-cavity the wall's radius varies by more than a voxel.
  const Vec3f c = shape.centre_mm();
  float rmin = 1e9f, rmax = 0.0f;
  for (int a = 0; a < 72; ++a) {
    const float th = static_cast<float>(a) * 6.2831853f / 72.0f;
    const Vec3f dir(std::cos(th), std::sin(th), 0.0f);
    float r = 0.0f;
    while (shape.target_sdf_mm(c + dir * r) < 0.0f) r += 0.05f;
    rmin = std::min(rmin, r), rmax = std::max(rmax, r);
  }
  EXPECT_GT((rmax - rmin) / spec.spacing_mm.x(), 1.5f);
  // The valve slab is brighter than the cavity and than ordinary tissue.
  double vs = 0, ts = 0;
  std::size_t vn = 0, tn = 0;
  for_each_voxel(spec, p, [&](std::size_t t, float sdf, float sector, const Vec3f& x) {
    if (sector <= 1.0f) return;
    if (shape.valve_sdf_mm(x) < -0.5f * spec.spacing_mm.x()) vs += p.image.u8()[t], ++vn;
    if (sdf > 8.0f && sdf < 14.0f) ts += p.image.u8()[t], ++tn;
  });
  ASSERT_GT(vn, 100u);
  EXPECT_GT(vs / vn, 1.4 * ts / tn);
}

TEST(SimEcho, WallDropsOutWhereItRunsAlongTheBeam) {
  // Sphere: the shell just outside the wall, split by the angle between the wall and the beam.
  const PhantomSpec spec = echo_spec("sphere", 64, 0.5f);
  const Phantom p = make_phantom(spec);
  const internal::Shape shape(spec, p.image.origin_mm());
  const internal::Sector sector(spec, p.image.origin_mm());
  double along = 0, facing = 0, far = 0;
  std::size_t na = 0, nf = 0, nt = 0;
  for_each_voxel(spec, p, [&](std::size_t t, float sdf, float in_sector, const Vec3f& x) {
    if (in_sector <= 1.0f) return;
    const double v = p.image.u8()[t];
    if (sdf > 6.0f && sdf < 10.0f) far += v, ++nt;
    if (sdf <= 0.0f || sdf >= 1.5f) return;
    const Vec3f normal = (x - shape.centre_mm()).normalized();
    const float cosine = std::abs(normal.dot((x - sector.apex_mm()).normalized()));
    if (cosine < 0.15f) along += v, ++na;
    if (cosine > 0.9f) facing += v, ++nf;
  });
  ASSERT_GT(na, 50u);
  ASSERT_GT(nf, 50u);
  EXPECT_LT(along / na, 0.85 * far / nt) << "dropout beside a wall along the beam";
  EXPECT_GT(facing / nf, 1.1 * far / nt) << "specular echo where the beam meets the wall";
  EXPECT_GT(facing / nf, 1.4 * along / na);
}

TEST(SimEcho, NearFieldClutterAndCompensatedAttenuation) {
  PhantomSpec spec = echo_spec("sphere", 64, 0.0f);  // contrast 0: tissue everywhere
  const Phantom p = make_phantom(spec);
  const internal::Sector sector(spec, p.image.origin_mm());
  const float R = 0.5f * 63.0f * spec.spacing_mm.x();
  auto mean_at_range = [&](float lo_R, float hi_R) {
    double s = 0;
    std::size_t n = 0;
    for_each_voxel(spec, p, [&](std::size_t t, float, float in_sector, const Vec3f& x) {
      const float r = sector.range_mm(x) / R;
      if (in_sector > 1.0f && r >= lo_R && r < hi_R) s += p.image.u8()[t], ++n;
    });
    return s / static_cast<double>(n);
  };
  const double near = mean_at_range(0.3f, 0.45f), mid = mean_at_range(1.2f, 1.4f);
  const double deep = mean_at_range(1.9f, 2.1f);
  EXPECT_GT(near, 1.3 * mid) << "near-field clutter";
  // 3 dB/cm over ~0.7 R = 11 mm is 3.3 dB (0.68x) uncompensated; the TGC leaves a fifth of it.
  EXPECT_LT(deep, 0.99 * mid);
  EXPECT_GT(deep, 0.8 * mid);
}

// The speckle's lateral correlation length in voxels: the first lag where the autocorrelation
// along x falls below 1/2, interpolated, over tissue at mid depth.
double lateral_grain_vox(const Phantom& p) {
  const Vec3i d = p.image.dims();
  const auto& v = p.image.u8();
  std::vector<double> c(8, 0.0);
  double mean = 0;
  std::size_t n = 0;
  for (int k = d.z() / 2 - 4; k < d.z() / 2 + 4; ++k)
    for (int j = 4; j < d.y() - 4; ++j)
      for (int i = 4; i < d.x() - 12; ++i) mean += v[p.image.linear_index(i, j, k)], ++n;
  mean /= static_cast<double>(n);
  for (int k = d.z() / 2 - 4; k < d.z() / 2 + 4; ++k)
    for (int j = 4; j < d.y() - 4; ++j)
      for (int i = 4; i < d.x() - 12; ++i) {
        const double a = v[p.image.linear_index(i, j, k)] - mean;
        for (int lag = 0; lag < 8; ++lag)
          c[lag] += a * (v[p.image.linear_index(i + lag, j, k)] - mean);
      }
  for (int lag = 1; lag < 8; ++lag)
    if (c[lag] / c[0] < 0.5) {
      const double hi = c[lag - 1] / c[0], lo = c[lag] / c[0];
      return lag - 1 + (hi - 0.5) / (hi - lo);
    }
  return 8.0;
}

TEST(SimEcho, SpeckleGrainScalesWithTheMmSetting) {
  PhantomSpec fine = echo_spec("sphere", 64, 0.0f);
  fine.speckle_mm = 0.5f;
  PhantomSpec coarse = fine;
  coarse.speckle_mm = 1.0f;
  const double g_fine = lateral_grain_vox(make_phantom(fine));
  const double g_coarse = lateral_grain_vox(make_phantom(coarse));
  EXPECT_NEAR(g_coarse / g_fine, 2.0, 0.4) << g_fine << " vs " << g_coarse;
  // The same grain in mm at half the spacing spans twice the voxels.
  PhantomSpec fine_grid = coarse;
  fine_grid.spacing_mm = Vec3f::Constant(0.25f);
  fine_grid.size_vox = 96;
  EXPECT_NEAR(lateral_grain_vox(make_phantom(fine_grid)) / g_coarse, 2.0, 0.4);
}

TEST(SimEcho, DeterministicPerSeed) {
  const PhantomSpec a = echo_spec("cyst-needle", 48, 0.5f, 7);
  PhantomSpec b = a;
  b.seed = 8;
  const Phantom pa = make_phantom(a);
  EXPECT_EQ(pa.image.u8(), make_phantom(a).image.u8());
  EXPECT_NE(pa.image.u8(), make_phantom(b).image.u8());
  // An echo stream and a simple one of the same seed do not disturb each other's bytes.
  PhantomSpec simple = a;
  simple.realism = Realism::Simple;
  const auto simple_bytes = make_phantom(simple).image.u8();
  EXPECT_NE(simple_bytes, pa.image.u8());
  EXPECT_EQ(make_phantom(a).image.u8(), pa.image.u8());
  EXPECT_EQ(make_phantom(simple).image.u8(), simple_bytes);
}

// The simple mode's bytes are those every earlier result was measured on.
TEST(SimEcho, SimpleModeBytesAreUnchanged) {
  PhantomSpec s;
  s.phantom = "cyst-needle";
  s.size_vox = 48;
  s.seed = 3;
  s.time_s = 1.3f;
  std::uint64_t h = 1469598103934665603ull;  // FNV-1a
  const Phantom p = make_phantom(s);
  for (std::uint8_t v : p.image.u8()) h = (h ^ v) * 1099511628211ull;
  EXPECT_EQ(h, 1746919354972704048ull)
      << "update only with a reason: simple-mode results depend on these bytes";
}

TEST(SimEcho, BadSpecsAndUris) {
  PhantomSpec s = echo_spec("lv", 48);
  s.speckle_mm = 0.0f;
  EXPECT_THROW(make_phantom(s), std::invalid_argument);
  EXPECT_THROW(parse_realism("photo"), std::invalid_argument);
  auto ok = parse_sim_uri("sim:lv?realism=echo&contrast=0.4&size=48");
  ASSERT_TRUE(ok) << ok.error().detail;
  EXPECT_EQ(ok->spec.realism, Realism::Echo);
  EXPECT_FLOAT_EQ(ok->spec.contrast, 0.4f);
  EXPECT_FLOAT_EQ(ok->spec.speckle, 1.0f);
  EXPECT_FALSE(parse_sim_uri("sim:lv?realism=photo"));
  EXPECT_FALSE(parse_sim_uri("sim:lv?oblique=2"));
  auto oblique = parse_sim_uri("torus?oblique=1&size=32");
  ASSERT_TRUE(oblique);
  const auto raw = make_stream_volume(*oblique, 0);
  const volume::Mat3f d = oblique_direction();
  EXPECT_FLOAT_EQ(raw.direction[3 * 1 + 2], d(2, 1));  // column-major: column 1, row 2
  EXPECT_TRUE((d.transpose() * d).isIdentity(1e-5f));
  EXPECT_FALSE(parse_sim_uri("sim:lv?contrast=2"));
}

}  // namespace
}  // namespace sonomesh::sim
