// The quality verdict on a pipeline result (DESIGN.md "Targets, polarity and the quality verdict").
#include <Eigen/Geometry>
#include <algorithm>
#include <cmath>

#include "daemon/internal/target_image.h"
#include "mesh/mesh.h"
#include "mesh/parallel.h"

namespace sonomesh::daemon::internal {
namespace {

using volume::Vec3i;

// A balloon whose vertices stopped, in the median, within this many voxels of the seed stalled on
// the texture around it (real echo at a one-voxel pre-filter: median 4.8 voxels from a start of
// 2, 0.28 mL in a ~50 mL cavity); the simulator's targets at 64³ reach 10 voxels and more.
constexpr float kStalledRadiusVox = 6.0f;
// How far past a needle's end its line is followed, voxel by voxel: from beyond the bright mask's
// end (its tip is dimmer) and clear of the dent the surface makes round it, to where a dent
// drawn on past the tip by the balloon's seam (7 voxels on a 96³ echo cyst-needle) ends.
constexpr int kBeyondEndFromVox = 4, kBeyondEndToVox = 8;
// A surface thinner (3V/A) than this many speckle grains (the pre-filter's sigma): the grains
// are as large as a quarter of the target, and the wall test takes them for its walls.
constexpr double kLeastGrainsThick = 4.25;
// Fewer voxels than a ball of 6 voxels' radius: no target a clinician would seed in this volume.
constexpr double kSmallestVoxels = 905.0;
// Share of the final surface's vertices allowed on the volume's edge or the sector's before the
// surface counts as touching it (a few vertices graze it on a target that fills the view).
constexpr double kTouchFraction = 0.01;
// The wall test of one vertex of the final surface: the smoothed image 2-5 voxels beyond it lies
// above the image 1-3 voxels inside by half the seed region's contrast. A surface that stopped on
// the texture inside a cavity, or ran out into the tissue, has the same level on both sides; the
// samples ahead begin at 2 voxels because the grain that stopped a vertex lies just ahead of it.
// (Echo phantoms at 96³: results with Dice >= 0.93 read 0.92-1.00, those stopped on speckle
// 0.06-0.65; the real coarse Philips ventricle 0.87, the CT spleen 0.94. docs/results.md.)
constexpr float kAheadFromVox = 2.0f;
constexpr float kAheadToVox = 5.0f;
constexpr float kBehindToVox = 3.0f;
constexpr float kWallRiseFraction = 0.5f;
constexpr float kLeastWallSupport = 0.75f;
// The open-patch test of one triangle: the smoothed image 1-5 voxels beyond it looks like the
// target's inside (its mean within 0.15 of the contrast above the target's level). A balloon
// stalled in a tube has caps that look down it; a surface on the wall sees brighter tissue within
// those voxels, unless the wall lies in a needle's shadow (the 256³ simple cyst-needle: tissue
// 36-43 there, the cyst behind it 15-25, its level elsewhere 31). With local levels, where the
// image 1-3 voxels behind the triangle is under 0.8 of the target's level (a shadow), it stands
// for the target's level and scales the rise, as a shadow darkens both sides by one factor.
constexpr float kOpenToVox = 5.0f;
constexpr float kOpenLevelFraction = 0.15f;
constexpr float kShadowFraction = 0.8f;
constexpr std::size_t kOpenGrain = 2048;           // triangles per task
constexpr std::size_t kWallSupportSamples = 4000;  // vertices tested, evenly spread over the list

double median_distance_mm(const std::vector<Vec3f>& points, const Vec3f& from) {
  if (points.empty()) return 0.0;
  std::vector<float> d;
  d.reserve(points.size());
  for (const Vec3f& p : points) d.push_back((p - from).norm());
  const auto mid = d.begin() + static_cast<std::ptrdiff_t>(d.size() / 2);
  std::nth_element(d.begin(), mid, d.end());
  return *mid;
}

// Vertices within a voxel of the voxel-centre box (no data beyond it).
std::size_t on_volume_edge(const volume::Volume& input, const std::vector<Vec3f>& points) {
  const Vec3f lo = input.min_mm() + input.spacing_mm(), hi = input.max_mm() - input.spacing_mm();
  return static_cast<std::size_t>(std::count_if(points.begin(), points.end(), [&](const Vec3f& p) {
    return (p.array() < lo.array()).any() || (p.array() > hi.array()).any();
  }));
}

// Vertices with a no-data voxel within two voxels (the balloon stops about one voxel inside the
// filled wall's edge after smoothing). The 5×5×5 block is read as its 25 rows along x, not voxel
// by voxel: the verdict runs on every tracked volume's surface (about 10 000 vertices at 128³).
std::size_t on_sector_edge(const volume::Volume& input, const std::vector<std::uint8_t>& no_data,
                           const std::vector<Vec3f>& points) {
  if (no_data.empty()) return 0;
  const Vec3i top = input.dims() - Vec3i::Ones();
  std::size_t n = 0;
  for (const Vec3f& p : points) {
    const Vec3i c = input.mm_to_index(p).array().round().cast<int>();
    const Vec3i lo = (c - Vec3i::Constant(2)).cwiseMax(Vec3i::Zero());
    const Vec3i hi = (c + Vec3i::Constant(2)).cwiseMin(top);
    if ((lo.array() > hi.array()).any()) continue;  // (beyond the volume: no voxel near)
    bool near = false;
    for (int k = lo.z(); k <= hi.z() && !near; ++k)
      for (int j = lo.y(); j <= hi.y() && !near; ++j) {
        const std::uint8_t* row = &no_data[input.linear_index(0, j, k)];
        near = std::any_of(row + lo.x(), row + hi.x() + 1, [](std::uint8_t v) { return v != 0; });
      }
    n += near ? 1 : 0;
  }
  return n;
}

// Mean of the smoothed image at p + n·d for d in [from, to] voxels, one sample per voxel.
float mean_along(const volume::Volume& smoothed, const Vec3f& p, const Vec3f& n, float from_vox,
                 float to_vox, float vox_mm) {
  float sum = 0.0f;
  int count = 0;
  for (float d = from_vox; d <= to_vox + 1e-3f; d += 1.0f, ++count)
    sum += volume::sample_mm(smoothed, p + n * (d * vox_mm));
  return sum / static_cast<float>(count);
}

}  // namespace

float wall_support(const volume::Volume& smoothed, const segment::Mesh& surface, float target_level,
                   float tissue_level) {
  const float contrast = tissue_level - target_level;
  if (smoothed.empty() || surface.vertices.empty() || !(contrast > 0.0f)) return -1.0f;
  const segment::PointCloud samples = mesh::oriented_samples(surface);
  const float vox_mm = smoothed.spacing_mm().minCoeff();
  const std::size_t n = samples.points.size();
  const std::size_t stride = std::max<std::size_t>(1, n / kWallSupportSamples);
  std::size_t walls = 0, tested = 0;
  for (std::size_t i = 0; i < n; i += stride, ++tested) {
    const Vec3f& p = samples.points[i];
    const Vec3f& normal = samples.normals[i];
    const float ahead = mean_along(smoothed, p, normal, kAheadFromVox, kAheadToVox, vox_mm);
    const float behind = mean_along(smoothed, p, -normal, 1.0f, kBehindToVox, vox_mm);
    walls += ahead - behind >= kWallRiseFraction * contrast ? 1 : 0;
  }
  return tested > 0 ? static_cast<float>(walls) / static_cast<float>(tested) : -1.0f;
}

float open_patch(const volume::Volume& smoothed, const segment::Mesh& surface, float target_level,
                 float tissue_level, int threads, bool local_levels) {
  const float contrast = tissue_level - target_level;
  if (smoothed.empty() || surface.triangles.empty() || !(contrast > 0.0f)) return -1.0f;
  const float vox_mm = smoothed.spacing_mm().minCoeff();
  std::vector<char> looks_inside(surface.triangles.size(), 0);
  mesh::Workers(threads).parallel_for(
      surface.triangles.size(), kOpenGrain, [&](std::size_t b, std::size_t e) {
        for (std::size_t i = b; i < e; ++i) {
          const auto& t = surface.triangles[i];
          const Vec3f &a = surface.vertices[t[0]], &p = surface.vertices[t[1]],
                      &c = surface.vertices[t[2]];
          const Vec3f cross = (p - a).cross(c - a);
          if (!(cross.norm() > 0.0f)) continue;  // (no direction to look in)
          const Vec3f centre = (a + p + c) / 3.0f, normal = cross.normalized();
          const float ahead = mean_along(smoothed, centre, normal, 1.0f, kOpenToVox, vox_mm);
          float level = target_level, rise = kOpenLevelFraction * contrast;
          const float behind =
              local_levels ? mean_along(smoothed, centre, -normal, 1.0f, kBehindToVox, vox_mm)
                           : target_level;
          if (target_level > 0.0f && behind < kShadowFraction * target_level) {
            rise *= behind / target_level;
            level = behind;
          }
          looks_inside[i] = ahead - level < rise;
        }
      });
  segment::Mesh open;
  open.vertices = surface.vertices;
  for (std::size_t i = 0; i < surface.triangles.size(); ++i)
    if (looks_inside[i]) open.triangles.push_back(surface.triangles[i]);
  double largest_mm2 = 0.0;
  for (const segment::Mesh& patch : mesh::connected_components(open))
    largest_mm2 = std::max(largest_mm2, mesh::surface_area_mm2(patch));
  const double total_mm2 = mesh::surface_area_mm2(surface);
  return total_mm2 > 0.0 ? static_cast<float>(largest_mm2 / total_mm2) : -1.0f;
}

bool needle_ends_inside(const segment::Mesh& surface, const std::array<Vec3f, 2>& ends,
                        float vox_mm) {
  // (A point outside the surface's box is outside it: past a through needle's ends most are, and
  // the ray test costs a pass over every triangle, 0.1 ms at 14 000.)
  const mesh::Box box = mesh::bounding_box(surface);
  const auto in_box = [&](const Vec3f& p) {
    return (p.array() >= box.lo_mm.array()).all() && (p.array() <= box.hi_mm.array()).all();
  };
  for (int e = 0; e < 2; ++e) {
    const Vec3f along = ends[e] - ends[1 - e];
    if (!(along.norm() > 0.0f)) return false;
    const Vec3f u = along.normalized();
    for (int k = kBeyondEndFromVox; k <= kBeyondEndToVox; ++k) {
      const Vec3f p = ends[e] + (static_cast<float>(k) * vox_mm) * u;
      if (in_box(p) && mesh::encloses(surface, p)) return true;
    }
  }
  return false;
}

// Whether the surface is thin for the speckle's grain (kLeastGrainsThick): the grain the
// pre-filter took, its sigma (a grain read longer than 3 voxels is anatomy, not speckle, and
// the pre-filter keeps one voxel: the coarse Philips volume).
bool thin_for_grain(const PipelineResult& result) {
  const double thickness_mm = mesh::thickness_mm(result.mesh);
  return result.smooth_sigma_mm > 0.0f && thickness_mm > 0.0 &&
         thickness_mm < kLeastGrainsThick * result.smooth_sigma_mm;
}

void balloon_reasons(const volume::Volume& input, const Vec3f& seed_mm,
                     const PipelineResult& result, std::vector<std::string>& why) {
  const float vox_mm = input.spacing_mm().minCoeff();
  if (result.balloon_stats.leaked) why.emplace_back("leak bound");
  // Sealed at a gap, the surface there is where the balloon was, not a wall; and a balloon that
  // ran out along a needle's shadow before it leaked is sealed just as well.
  if (result.balloon_stats.leak_seals > 0) why.emplace_back("leak sealed");
  if (!result.balloon.vertices.empty() &&
      median_distance_mm(result.balloon.vertices, seed_mm) < kStalledRadiusVox * vox_mm)
    why.emplace_back("stalled near the seed");
  const std::size_t balloon_n = result.balloon.vertices.size();
  if (balloon_n > 0 && result.stop_counts.iteration_limit > static_cast<int>(0.005 * balloon_n) &&
      result.stop_counts.iteration_limit > 0)
    why.emplace_back("iteration limit");
}

void quality_verdict(const volume::Volume& input, const volume::Volume& smoothed,
                     const std::vector<std::uint8_t>& no_data, const Vec3f& seed_mm,
                     PipelineResult& result) {
  std::vector<std::string>& why = result.quality_reasons;
  why.clear();
  balloon_reasons(input, seed_mm, result, why);
  if (result.ok) {
    const double voxel_ml = input.spacing_mm().prod() * 1e-3;
    if (result.enclosed_volume_ml < kSmallestVoxels * voxel_ml)
      why.emplace_back("implausibly small");
    const auto& points = result.mesh.vertices;
    const double limit = kTouchFraction * static_cast<double>(points.size());
    if (static_cast<double>(on_volume_edge(input, points)) > limit)
      why.emplace_back("touches the volume edge");
    if (static_cast<double>(on_sector_edge(input, no_data, points)) > limit)
      why.emplace_back("touches the sector edge");
    if (result.topology.components != 1 || !result.topology.watertight)
      why.emplace_back("not one closed surface");
    // Columns are filled only on an implausible surface: what it became is a reader's to check.
    if (result.topology.genus > kMostHandles)
      why.emplace_back("implausible genus");
    else if (result.tissue_columns_filled)
      why.emplace_back("tissue columns filled");
    // The needle's tip lies in the cavity: a handle is not its tunnel, and its walls inside the
    // surface make the dent it is.
    // (Asked only where it changes a reason: a handle, or a bright structure left inside.)
    const bool tip_inside =
        result.needle_ends_mm && (result.topology.genus >= 1 || result.bright_inside_left) &&
        needle_ends_inside(result.mesh, *result.needle_ends_mm, input.spacing_mm().minCoeff());
    if (tip_inside && result.topology.genus >= 1) why.emplace_back("needle ends inside");
    if (thin_for_grain(result)) why.emplace_back("thin for the speckle grain");
    result.wall_support = result.fitted_wall_support >= 0.0f
                              ? result.fitted_wall_support
                              : wall_support(smoothed, result.mesh, result.balloon_stats.seed_level,
                                             result.balloon_stats.tissue_level);
    if (result.wall_support >= 0.0f && result.wall_support < kLeastWallSupport)
      why.emplace_back("surface not on the target's wall");
    // A bright structure across the target whose walls opened no tunnel: a needle's handle is
    // missing, or the surface stopped at clutter across the cavity.
    if (result.bright_inside_left && !tip_inside) why.emplace_back("bright structure inside");
    // A dark target's image is the echo's amplitude, whose zero is no echo (a bright target's
    // working image is inverted about its maximum: its levels have no such zero).
    if (result.target == TargetPolarity::Dark && segment::low_contrast(result.balloon_stats))
      why.emplace_back("low contrast");
    // At the coarse retry's scale a surface a few voxels inside the wall still sees the wall
    // ahead: the wall test cannot tell it from one on the wall, so the result is never ok.
    if (result.coarse_retry) why.emplace_back("coarse pre-filter");
    if (result.unconfirmed) why.emplace_back("not confirmed by the other stop rule");
  } else if (why.empty()) {
    why.emplace_back("failed");
  }
  result.quality_ok = why.empty();
}

}  // namespace sonomesh::daemon::internal
