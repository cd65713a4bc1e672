// Acoustic shadows lifted before the balloon sees the image (shadow_gain.h).
#include "daemon/internal/shadow_gain.h"

#include <Eigen/Dense>
#include <algorithm>
#include <array>
#include <cmath>
#include <limits>
#include <map>

#include "daemon/internal/bright_mask.h"
#include "mesh/parallel.h"

namespace sonomesh::daemon::internal {
namespace {

using volume::Vec3f;
using volume::Vec3i;
using volume::Volume;

// A caster and its 7-voxel cross lie over this many times the sector's median: a needle reaches
// 2-3 times the tissue's echo, a tissue wall's specular echo under 1.8 times, speckle averaged
// over a cross rarely that.
constexpr float kCasterLevel = 1.8f;
// The beam's mean beyond a caster against the mean beside it: below this it is a shadow (a
// caster with tissue beyond it like beside it reads 1).
constexpr float kShadowRatio = 0.6f;
// A cluster with fewer casters than this is speckle that passed the tests by chance.
constexpr std::size_t kMinCasters = 20, kMostTested = 256;
// ... and a cluster shorter than this along every axis is a grain or a blob, not a needle.
constexpr int kMinLengthVox = 12;
// A cluster that does not cast as a whole is judged again in blocks of this edge.
constexpr int kBlockVox = 24;
// Beyond: voxels 3-20 along the beam, past the reflector itself; beside: 6 voxels across the beam,
// clear of a needle's shadow (its radius is 1.2-2.5 voxels in our phantoms).
constexpr int kBeyondFirstVox = 3, kBeyondLastVox = 20;
constexpr float kBesideVox = 6.0f;
// A search near the last volume's casters scans their box grown by this much: a needle moves a
// few voxels between volumes as the target breathes.
constexpr int kNearMarginVox = 6;

// The sector's median and 90th percentile (every 29th data voxel).
struct SectorLevels {
  float median = 0.0f, p90 = 0.0f;
};

SectorLevels sector_levels(const Volume& image, const std::vector<std::uint8_t>& no_data) {
  std::vector<float> sample;
  const std::vector<float>& v = image.f32();
  for (std::size_t at = 0; at < v.size(); at += 29)
    if (!no_data[at]) sample.push_back(v[at]);
  return {quantile(sample, 0.5f), quantile(sample, 0.9f)};
}

// The index box holding the voxels.
IndexBox bounding_box(const Vec3i& d, const std::vector<std::size_t>& voxels) {
  IndexBox box{d, Vec3i::Zero()};
  for (const std::size_t v : voxels) {
    const Vec3i x = index_of(d, v);
    box.lo = box.lo.cwiseMin(x), box.hi = box.hi.cwiseMax(x);
  }
  return box;
}

// The longest side of the index box holding the voxels.
int longest_side_vox(const Vec3i& d, const std::vector<std::size_t>& voxels) {
  const IndexBox box = bounding_box(d, voxels);
  return (box.hi - box.lo).maxCoeff() + 1;
}

// The beams of a sector: rays from the apex, read at whole voxels (nearest), within the data.
struct Beams {
  const Volume& image;
  const std::vector<std::uint8_t>& no_data;
  Vec3f apex_mm;
  float vox_mm;
  float tissue_top;  // the sector's 90th percentile: a mean beside a shadow is rarely over it

  Vec3f at_mm(std::size_t voxel) const {
    return image.index_to_mm(index_of(image.dims(), voxel).cast<float>());
  }

  // The voxel nearest to q in the data, or -1 (outside the volume or the sector).
  std::ptrdiff_t voxel(const Vec3f& q) const {
    const Vec3f x = image.mm_to_index(q);
    const Vec3i v(static_cast<int>(std::lround(x.x())), static_cast<int>(std::lround(x.y())),
                  static_cast<int>(std::lround(x.z())));
    if (!image.contains_index(v)) return -1;
    const std::size_t at = image.linear_index(v.x(), v.y(), v.z());
    return no_data[at] ? -1 : static_cast<std::ptrdiff_t>(at);
  }

  // Mean along the beam b from q, kBeyondFirstVox..kBeyondLastVox voxels on; -1 where that
  // leaves the data (the sector's end is no shadow).
  float mean_beyond(const Vec3f& q, const Vec3f& b) const {
    float sum = 0.0f;
    for (int s = kBeyondFirstVox; s <= kBeyondLastVox; ++s) {
      const std::ptrdiff_t at = voxel(q + (static_cast<float>(s) * vox_mm) * b);
      if (at < 0) return -1.0f;
      sum += image.f32()[static_cast<std::size_t>(at)];
    }
    return sum / static_cast<float>(kBeyondLastVox - kBeyondFirstVox + 1);
  }

  // Whether the beam through p leaves the bright structure (the mask) within a voxel and a half:
  // the far side of a reflector, where its shadow starts.
  bool far_side(const Vec3f& p, const BrightMask& bright) const {
    const std::ptrdiff_t at = voxel(p + (1.5f * vox_mm) * (p - apex_mm).normalized());
    return at >= 0 && !bright.bright(static_cast<std::size_t>(at));
  }

  // The shadow's level beyond p over the level beside it (1: no shadow): of four directions
  // across the beam (45° apart), the one whose darker side is brightest beyond. A needle's shadow
  // has tissue on both sides; the edge of a dark cavity beyond a wall has it on one side only.
  float shadow_ratio(const Vec3f& p) const {
    const Vec3f b = (p - apex_mm).normalized();
    const float beyond = mean_beyond(p, b);
    if (beyond < 0.0f || beyond >= kShadowRatio * tissue_top) return 1.0f;
    const Vec3f helper = std::abs(b.x()) < 0.9f ? Vec3f::UnitX() : Vec3f::UnitY();
    const Vec3f u = b.cross(helper).normalized(), w = b.cross(u);
    float beside = 0.0f;
    for (const Vec3f& a : {u, w, Vec3f((u + w).normalized()), Vec3f((u - w).normalized())}) {
      const Vec3f off = (kBesideVox * vox_mm) * a;
      const float one = mean_beyond(p + off, b);
      if (one * kShadowRatio <= beyond) continue;  // no brighter than the shadow, or no data
      beside = std::max(beside, std::min(one, mean_beyond(p - off, b)));
    }
    return beside > 0.0f ? beyond / beside : 1.0f;
  }

  // The shadow ratios of the cluster's far side, when it casts: at least kMinCasters of them
  // under kShadowRatio, a third of the far side or more (a bright tissue wall's far side has a
  // few by chance). Empty otherwise. At most about kMostTested voxels of the far side are tested,
  // evenly spread: a large bright structure costs no more than a needle.
  std::vector<float> cluster_ratios(const std::vector<std::size_t>& cluster,
                                    const BrightMask& bright) const {
    std::vector<Vec3f> far;
    const std::size_t step = cluster.size() / (8 * kMostTested) + 1;  // (a large cluster: a sample)
    for (std::size_t c = 0; c < cluster.size(); c += step)
      if (const Vec3f p = at_mm(cluster[c]); far_side(p, bright)) far.push_back(p);
    const std::size_t stride = far.size() / kMostTested + 1;
    std::vector<float> ratios;
    std::size_t tested = 0;
    for (std::size_t f = 0; f < far.size(); f += stride) {
      ++tested;
      if (const float ratio = shadow_ratio(far[f]); ratio < kShadowRatio) ratios.push_back(ratio);
      // (Far from a third after each 32 tests: a bright tissue wall; the rest would not change it.)
      if (tested % 32 == 0 && 6 * ratios.size() < tested) return {};
    }
    if (ratios.size() < kMinCasters || 3 * ratios.size() < tested) ratios.clear();
    return ratios;
  }
};

// The casters' shadow seen from the apex: over the beams' directions (tangents in a frame whose
// third axis is the casters' mean beam), the farthest range of a caster on each beam. A voxel lies
// in the shadow when a caster on its beam is nearer than it by more than a voxel (the reflector's
// own blurred far edge is not lifted), partly so on the shadow's edge. A map of directions has no
// gaps where the beams fan out beyond the reflector, as beams traced from its voxels would.
class ShadowMap {
 public:
  ShadowMap(const Beams& beams, const std::vector<std::size_t>& casters) : beams_(beams) {
    Vec3f mean = Vec3f::Zero();
    for (const std::size_t c : casters) mean += (beams.at_mm(c) - beams.apex_mm).normalized();
    e3_ = mean.normalized();
    e1_ = e3_.cross(std::abs(e3_.x()) < 0.9f ? Vec3f::UnitX() : Vec3f::UnitY()).normalized();
    e2_ = e3_.cross(e1_);
    Eigen::Vector2f lo = Eigen::Vector2f::Constant(1e9f), hi = -lo;
    float nearest = std::numeric_limits<float>::max(), farthest = 0.0f;
    for (const std::size_t c : casters) {
      const Vec3f d = beams.at_mm(c) - beams.apex_mm;
      if (!ahead(d)) continue;
      lo = lo.cwiseMin(tangent(d)), hi = hi.cwiseMax(tangent(d));
      nearest = std::min(nearest, d.dot(e3_)), farthest = std::max(farthest, d.dot(e3_));
    }
    if (!(farthest > 0.0f)) return;  // (no caster ahead of the apex: an empty map)
    // A caster covers 0.7 voxel around its centre; cells of half a voxel at the farthest depth,
    // coarser where that would take more than kMostCells a side.
    const float reach = kFootprintVox * beams.vox_mm / nearest;
    lo_ = lo.array() - reach;
    const Eigen::Vector2f span = (hi - lo).array() + 2.0f * reach;
    cell_ = std::max(0.5f * beams.vox_mm / farthest, span.maxCoeff() / kMostCells);
    nu_ = static_cast<int>(span.x() / cell_) + 1;
    nv_ = static_cast<int>(span.y() / cell_) + 1;
    far_mm_.assign(static_cast<std::size_t>(nu_) * nv_, 0.0f);
    for (const std::size_t c : casters)
      if (const Vec3f d = beams.at_mm(c) - beams.apex_mm; ahead(d)) mark(d);
    soften_edge();
  }

  // How deep p lies in the shadow: 1 inside it, 0 outside, between on its edge.
  float depth_in(const Vec3f& p_mm) const {
    const Vec3f d = p_mm - beams_.apex_mm;
    if (far_mm_.empty() || !ahead(d)) return 0.0f;
    const Eigen::Vector2f t = (tangent(d) - lo_) / cell_;
    const int u = static_cast<int>(t.x()), v = static_cast<int>(t.y());
    if (t.x() < 0.0f || t.y() < 0.0f || u >= nu_ || v >= nv_) return 0.0f;
    const std::size_t at = static_cast<std::size_t>(v) * nu_ + u;
    return d.norm() > edge_far_mm_[at] + beams_.vox_mm ? edge_cover_[at] : 0.0f;
  }

 private:
  static constexpr float kFootprintVox = 0.7f;
  static constexpr int kMostCells = 1024;

  // Whether d (from the apex) points ahead of it, a voxel or more along the casters' beam.
  bool ahead(const Vec3f& d) const { return d.dot(e3_) >= beams_.vox_mm; }

  Eigen::Vector2f tangent(const Vec3f& d) const {
    return Eigen::Vector2f(d.dot(e1_), d.dot(e2_)) / d.dot(e3_);
  }

  // The cells within the caster's footprint (kFootprintVox at its depth, and at least its own
  // cell) take its range.
  void mark(const Vec3f& d) {
    const float depth = d.dot(e3_), range = d.norm();
    const float r = std::max(0.75f, kFootprintVox * beams_.vox_mm / depth / cell_);
    const Eigen::Vector2f t = (tangent(d) - lo_) / cell_;
    for (int v = std::max(0, static_cast<int>(t.y() - r));
         v <= std::min(nv_ - 1, static_cast<int>(t.y() + r)); ++v)
      for (int u = std::max(0, static_cast<int>(t.x() - r));
           u <= std::min(nu_ - 1, static_cast<int>(t.x() + r)); ++u) {
        const Eigen::Vector2f c(static_cast<float>(u) + 0.5f, static_cast<float>(v) + 0.5f);
        if ((c - t).squaredNorm() > r * r) continue;
        float& far = far_mm_[static_cast<std::size_t>(v) * nu_ + u];
        far = std::max(far, range);
      }
  }

  // The shadow's edge over the cells around each: the share of them marked and the farthest
  // caster among them. The simulator's and a probe's shadows fade over about a voxel.
  void soften_edge() {
    edge_cover_.assign(far_mm_.size(), 0.0f);
    edge_far_mm_.assign(far_mm_.size(), 0.0f);
    for (int v = 0; v < nv_; ++v)
      for (int u = 0; u < nu_; ++u) {
        int marked = 0;
        float far = 0.0f;
        for (int b = std::max(0, v - 1); b <= std::min(nv_ - 1, v + 1); ++b)
          for (int a = std::max(0, u - 1); a <= std::min(nu_ - 1, u + 1); ++a) {
            const float f = far_mm_[static_cast<std::size_t>(b) * nu_ + a];
            marked += f > 0.0f;
            far = std::max(far, f);
          }
        const std::size_t at = static_cast<std::size_t>(v) * nu_ + u;
        edge_cover_[at] = static_cast<float>(marked) / 9.0f;
        edge_far_mm_[at] = far;
      }
  }

  const Beams& beams_;
  Vec3f e1_, e2_, e3_;
  Eigen::Vector2f lo_;
  float cell_ = 1.0f;
  int nu_ = 0, nv_ = 0;
  std::vector<float> far_mm_;  // per cell; 0: no caster
  std::vector<float> edge_cover_, edge_far_mm_;
};

// The index box holding every voxel the casters' shadow can reach: the casters, and their beams
// out to the range of the volume's farthest corner.
std::pair<Vec3i, Vec3i> shadow_box(const Beams& beams, const std::vector<std::size_t>& casters) {
  const Volume& image = beams.image;
  const Vec3i top = image.dims() - Vec3i::Ones();
  float reach_mm = 0.0f;
  for (int c = 0; c < 8; ++c) {
    const Vec3f corner(c & 1 ? top.x() : 0, c & 2 ? top.y() : 0, c & 4 ? top.z() : 0);
    reach_mm = std::max(reach_mm, (image.index_to_mm(corner) - beams.apex_mm).norm());
  }
  Vec3f lo = Vec3f::Constant(std::numeric_limits<float>::max()), hi = -lo;
  for (const std::size_t c : casters) {
    const Vec3f p = beams.at_mm(c), d = p - beams.apex_mm;
    if (d.norm() < beams.vox_mm) continue;  // (at the apex: no beam; ShadowMap leaves it out)
    for (const Vec3f& q : {p, Vec3f(beams.apex_mm + d * (reach_mm / d.norm()))}) {
      const Vec3f x = image.mm_to_index(q);
      lo = lo.cwiseMin(x), hi = hi.cwiseMax(x);
    }
  }
  const Vec3i from = lo.array().floor().cast<int>().max(0).matrix();
  const Vec3i to = hi.array().ceil().cast<int>().min(top.array()).matrix();
  return {from, to};
}

// Multiplies every data voxel in the casters' shadow (and in `within`, when given) by `lift`
// (less on its edge); counts them into `lifted`.
void lift_shadow(const Beams& beams, const std::vector<std::size_t>& casters, float lift,
                 int threads, const IndexBox* within, Volume& image, std::size_t& lifted) {
  const ShadowMap shadow(beams, casters);
  // (Not a structured binding: the lambda below captures the box, which clang 14 refuses.)
  const std::pair<Vec3i, Vec3i> box = shadow_box(beams, casters);
  const Vec3i from = within ? box.first.cwiseMax(within->lo) : box.first;
  const Vec3i to = within ? box.second.cwiseMin(within->hi) : box.second;
  std::vector<float>& v = image.f32();
  std::vector<std::size_t> counts(static_cast<std::size_t>(threads), 0);
  mesh::parallel_chunks(
      from.z(), to.z() + 1, static_cast<int>(counts.size()), [&](int k0, int k1, int c) {
        for (int k = k0; k < k1; ++k)
          for (int j = from.y(); j <= to.y(); ++j)
            for (int i = from.x(); i <= to.x(); ++i) {
              const std::size_t at = image.linear_index(i, j, k);
              if (beams.no_data[at]) continue;
              const float depth = shadow.depth_in(image.index_to_mm(Vec3f(i, j, k)));
              if (depth > 0.0f) v[at] *= 1.0f + (lift - 1.0f) * depth, ++counts[c];
            }
      });
  for (const std::size_t n : counts) lifted += n;
}

// The parts of a cluster (`length_vox` its longest side) that cast, their ratios added to
// `ratios`: the cluster, or when it does not cast as a whole and spans more than a block, its
// parts in each kBlockVox³ block. (A steep
// needle enters through the near field's bright clutter and joins its cluster, whose far side
// as a whole does not cast.)
std::vector<std::vector<std::size_t>> casting_parts(const Beams& beams,
                                                    const std::vector<std::size_t>& cluster,
                                                    int length_vox, const BrightMask& bright,
                                                    std::vector<float>& ratios) {
  std::vector<std::vector<std::size_t>> parts;
  const auto take = [&](const std::vector<std::size_t>& part) {
    const std::vector<float> found = beams.cluster_ratios(part, bright);
    if (found.empty()) return;
    ratios.insert(ratios.end(), found.begin(), found.end());
    parts.push_back(part);
  };
  take(cluster);
  const Vec3i d = beams.image.dims();
  if (!parts.empty() || length_vox <= kBlockVox) return parts;
  std::map<std::array<int, 3>, std::vector<std::size_t>> blocks;
  for (const std::size_t v : cluster) {
    const Vec3i b = index_of(d, v) / kBlockVox;
    blocks[{b.x(), b.y(), b.z()}].push_back(v);
  }
  for (const auto& [key, part] : blocks)
    if (part.size() >= kMinCasters) take(part);
  return parts;
}

// The casters among the mask's clusters (`ones` its voxels, each marked 2 as its cluster is
// taken), their shadow ratios added to `ratios`, both in the clusters' order whatever the threads
// did. Only clusters of kMinCasters voxels or more, kMinLengthVox voxels long or more, are
// judged (a needle is a line; a speckle grain or a clutter blob is short): about 40 on a 128³
// echo volume, most of them the near field's clutter.
std::vector<std::size_t> find_casters(const Beams& beams, const std::vector<std::size_t>& ones,
                                      int threads, BrightMask& bright, std::vector<float>& ratios) {
  const Vec3i d = beams.image.dims();
  std::vector<std::pair<std::vector<std::size_t>, int>> lines;  // voxels, longest side
  std::vector<std::size_t> cluster;
  for (const std::size_t at : ones) {
    if (!bright.untaken(at)) continue;  // (taken with an earlier cluster)
    bright.take_cluster(at, cluster);
    if (cluster.size() < kMinCasters) continue;
    if (const int length_vox = longest_side_vox(d, cluster); length_vox >= kMinLengthVox)
      lines.emplace_back(cluster, length_vox);
  }
  std::vector<std::vector<std::vector<std::size_t>>> parts(lines.size());
  std::vector<std::vector<float>> found(lines.size());
  mesh::Workers(threads).parallel_for(lines.size(), 1, [&](std::size_t b, std::size_t e) {
    for (std::size_t c = b; c < e; ++c)
      parts[c] = casting_parts(beams, lines[c].first, lines[c].second, bright, found[c]);
  });
  std::vector<std::size_t> casters;
  for (std::size_t c = 0; c < lines.size(); ++c) {
    ratios.insert(ratios.end(), found[c].begin(), found[c].end());
    for (const auto& part : parts[c]) casters.insert(casters.end(), part.begin(), part.end());
  }
  return casters;
}

// The casters among the clusters that have a bright voxel in `box` (grown whole beyond it), their
// ratios in `ratios` (cleared first).
std::vector<std::size_t> casters_in(const Beams& beams, float level, int threads,
                                    const IndexBox& box, std::vector<float>& ratios) {
  BrightMask bright(beams.image, level);
  std::vector<std::size_t> ones;
  bright.scan(box, threads, ones);
  ratios.clear();
  return find_casters(beams, ones, threads, bright, ratios);
}

// The casters' ends along their principal line (the largest eigenvector of their scatter).
std::array<Vec3f, 2> line_ends(const Beams& beams, const std::vector<std::size_t>& casters) {
  Vec3f mean = Vec3f::Zero();
  for (const std::size_t c : casters) mean += beams.at_mm(c);
  mean /= static_cast<float>(casters.size());
  Eigen::Matrix3f scatter = Eigen::Matrix3f::Zero();
  for (const std::size_t c : casters) {
    const Vec3f d = beams.at_mm(c) - mean;
    scatter += d * d.transpose();
  }
  const Vec3f axis = Eigen::SelfAdjointEigenSolver<Eigen::Matrix3f>(scatter).eigenvectors().col(2);
  float lo = 0.0f, hi = 0.0f;
  for (const std::size_t c : casters) {
    const float t = (beams.at_mm(c) - mean).dot(axis);
    lo = std::min(lo, t), hi = std::max(hi, t);
  }
  return {Vec3f(mean + lo * axis), Vec3f(mean + hi * axis)};
}

IndexBox grown(const IndexBox& box, int by_vox) {
  return {box.lo - Vec3i::Constant(by_vox), box.hi + Vec3i::Constant(by_vox)};
}

}  // namespace

float quantile(std::vector<float> v, float q) {
  if (v.empty()) return 0.0f;
  const auto mid = v.begin() + static_cast<std::ptrdiff_t>(q * static_cast<float>(v.size() - 1));
  std::nth_element(v.begin(), mid, v.end());
  return *mid;
}

// One factor for the volume, the casters' median: a single caster's ratio varies with the speckle
// along its beam (the lower quartile over-lifted and made columns of lifted speckle).
ShadowGain compensate_shadows(Volume& image, const std::vector<std::uint8_t>& no_data,
                              const Vec3f& apex_mm, int threads, const IndexBox* near,
                              const IndexBox* within) {
  ShadowGain gain;
  if (no_data.empty() || image.type() != volume::VoxelType::Float32) return gain;
  const SectorLevels levels = sector_levels(image, no_data);
  // Casters lie over kCasterLevel times the median and over the 90th percentile (a sector that
  // is mostly dark cavity or dropout has a low median).
  const float level = std::max(kCasterLevel * levels.median, levels.p90);
  if (!(level > 0.0f)) return gain;
  gain.bright_level = level;
  const Beams beams{image, no_data, apex_mm, image.spacing_mm().minCoeff(), levels.p90};
  threads = mesh::Workers::resolved(threads);
  std::vector<float> ratios;
  std::vector<std::size_t> casters;
  if (near) casters = casters_in(beams, level, threads, grown(*near, kNearMarginVox), ratios);
  gain.searched_near = !casters.empty();
  if (casters.empty())
    casters = casters_in(beams, level, threads, {Vec3i::Zero(), image.dims()}, ratios);
  if (casters.empty()) return gain;
  gain.casters = static_cast<int>(casters.size());
  gain.shadow_factor = std::max(0.1f, quantile(ratios, 0.5f));
  gain.casters_box = bounding_box(image.dims(), casters);
  gain.ends_mm = line_ends(beams, casters);
  lift_shadow(beams, casters, 1.0f / gain.shadow_factor, threads, within, image, gain.voxels);
  return gain;
}

}  // namespace sonomesh::daemon::internal
