// The second opinion and the coarse retry (opinions.h): the pipeline's stages run again with
// the other stop rule or a coarser pre-filter, and the better result kept.
#include "daemon/internal/opinions.h"

#include <algorithm>
#include <string>
#include <utility>
#include <vector>

#include "daemon/internal/stages.h"
#include "daemon/internal/target_image.h"

namespace sonomesh::daemon::internal {
namespace {

// `config` with the second opinion's level stop on, or as it is.
PipelineConfig with_level_stop(const PipelineConfig& config, bool level) {
  PipelineConfig c = config;
  if (level) c.balloon.level_stop_fraction = config.second_opinion_level_stop;
  return c;
}

// Whether `other` is the better of two results: a surface before none, an ok verdict before a
// suspect one, between two suspect ones the larger wall support (the verdict's own measure of a
// surface on the target's wall rather than on speckle or in the tissue), and between two ok ones
// the smaller open patch without losing a handle (a stalled balloon finds none, and a stop that
// closed a needle's thin tunnel at a small size looks as open as one that kept it).
bool better(const PipelineResult& other, const PipelineResult& first) {
  if (other.ok != first.ok) return other.ok;
  if (!other.ok) return false;
  if (other.quality_ok != first.quality_ok) return other.quality_ok;
  if (!other.quality_ok) return other.wall_support > first.wall_support;
  return other.open_patch >= 0.0f && other.open_patch < first.open_patch &&
         other.topology.genus >= first.topology.genus;
}

// An ok result whose largest patch looking into the target's inside is beyond this share of its
// area may have stalled in a tube (a torus's, at 64³ and contrast 0.5): the second opinion is
// asked for. The verdict stands, because a real left ventricle's base opens onto the atrium.
constexpr float kOpenPatchForSecondOpinion = 0.012f;

// A target whose deepest point lies under this many voxels from its surface (a tube at most 12
// voxels across) may have stalled in it with its caps on a grain, which the open patch does not
// see (the 64³ echo double torus at contrast 0.7: genus 0, Dice 0.81, every test passed); the
// second opinion is asked, which at that size costs 20-30 ms.
constexpr float kThinTargetVox = 6.0f;
// Caps on grains across a tube close it: a genus-0 result this thin is asked too (the 96³ echo
// double torus at contrast 0.5 and 0.8 s: 7.3 voxels deep, Dice 0.33, open 1.15 % and every
// other test passed). Right genus-0 targets in the sweeps lie 9.5 voxels deep or more (the 64³
// echo ventricle); a genus-1 cyst-needle at 64³, 6-8 voxels deep, is not asked again.
constexpr float kThinGenusZeroVox = 8.0f;

// An ok result the second opinion was asked of (it looked open or thin) may have stalled in a
// tube with its caps on grains, which its own tests pass; an ok other result replaces it. An
// other that stalled near the seed, or whose surface (ok or not) encloses more than this many
// times the volume, leaves that doubt standing: where both are right they lie within 1.6 of
// each other (the 64³ echo double torus at contrast 0.5, seeded 0.45 of the radius along −x:
// Dice 0.38, genus 0, its other stalled near the seed; the 128³ one from other levels: 0.85
// against 4.4 mL, Dice 0.20, the other's surface missing the seed). An other that leaked to the
// bound says nothing of the first: a right 64³ cyst-needle's did.
constexpr double kShortOfOtherRatio = 2.0;
// An other whose reconstruction failed encloses little whatever its balloon reached: a balloon
// that did not leak and whose box holds more than this many times the first surface's box leaves
// the doubt too (the 96³ echo double torus at contrast 0.5, seed 4, 3 s: Ψ_cost stalled in one
// tube, Dice 0.42, its level stop ran through both loops, box 3.5 times, and its surface missed
// the seed). Asked ok results whose other failed or was suspect: 1.74 times at most.
constexpr double kOtherBoxRatio = 2.5;

double box_volume_mm3(const segment::Mesh& surface) {
  const mesh::Box box = mesh::bounding_box(surface);
  return static_cast<double>((box.hi_mm - box.lo_mm).prod());
}

bool leaves_doubt(const PipelineResult& first, const PipelineResult& other) {
  if (other.enclosed_volume_ml > kShortOfOtherRatio * first.enclosed_volume_ml) return true;
  // The other passed over a bright structure across the target (a needle) that the first has
  // no tunnel for: a 64³ echo cyst-needle at contrast 0.6 seeded off the centre came out genus
  // 0 and ok, its other "bright structure inside".
  if (other.bright_inside_opened && first.topology.genus == 0) return true;
  if (!other.balloon_stats.leaked && !other.balloon.vertices.empty() &&
      box_volume_mm3(other.balloon) > kOtherBoxRatio * box_volume_mm3(first.mesh))
    return true;
  return std::any_of(other.quality_reasons.begin(), other.quality_reasons.end(),
                     [](const std::string& why) {
                       return why == "stalled near the seed" || why == "implausibly small";
                     });
}

bool thin(const volume::Volume& input, const PipelineResult& r) {
  const float thin_vox = r.topology.genus == 0 ? kThinGenusZeroVox : kThinTargetVox;
  return r.deepest_depth_mm > 0.0f && r.deepest_depth_mm < thin_vox * input.spacing_mm().minCoeff();
}

// A genus-0 result thin enough to be a tube's stall with its caps on grains (the 64³ echo double
// torus at contrast 0.4, seed 3: genus 0, Dice 0.59, the level stop's after a suspect Ψ_cost).
bool thin_and_closed(const volume::Volume& input, const PipelineResult& r) {
  return r.topology.genus == 0 && thin(input, r);
}

// Two ok results that look as open: a first thin and closed (asked as a tube's stall with its
// caps on grains) gives way to an other that is not thin, of as many handles. (The 64³ echo
// ventricle of seed 4 at contrast 0.5, Ψ_cost first, since the wall fit's along-beam crossing:
// both open 0, Ψ_cost's thin result Dice 0.906, the level stop's 0.952.)
bool deeper_of_two_closed(const volume::Volume& input, const PipelineResult& first,
                          const PipelineResult& other) {
  return first.ok && first.quality_ok && other.ok && other.quality_ok && other.open_patch >= 0.0f &&
         other.open_patch <= first.open_patch && other.topology.genus >= first.topology.genus &&
         thin_and_closed(input, first) && !thin(input, other);
}

// Measures `r`'s open patch (it is ok) and says whether it asks for the second opinion: only if
// it is still open against the levels behind it. A wall in a needle's shadow looks open against
// the target's level; the level stop would run along the shadow and be sealed there, never
// better (256³ simple cyst-needle: 3 s). The report and the tracker keep the plain measure.
bool open_widely(const PipelineBuffers& buffers, int threads, PipelineResult& r) {
  const segment::BalloonStats& stats = r.balloon_stats;
  r.open_patch =
      open_patch(buffers.smoothed, r.mesh, stats.seed_level, stats.tissue_level, threads);
  return r.open_patch > kOpenPatchForSecondOpinion &&
         open_patch(buffers.smoothed, r.mesh, stats.seed_level, stats.tissue_level, threads, true) >
             kOpenPatchForSecondOpinion;
}

// An ok result taken in place of a suspect first opinion has nothing to confirm it where it
// looks open (in the echo sweep with seeds across the inner half such results were the only
// wrong ones: a 96³ torus's and a double torus's stall in a tube, open 5.1 and 1.3 % against
// 0.13 % at most) or is thin and closed: then it is suspect too, "not confirmed".
void confirm_in_place(const volume::Volume& input, const PipelineBuffers& buffers, int threads,
                      const Judge& judge, const std::string& error, PipelineResult& taken) {
  if (!(open_widely(buffers, threads, taken) || thin_and_closed(input, taken))) return;
  taken.unconfirmed = true;
  judge(taken, error);
}

// The coarse retry's sigma: `grains` speckle grains, 2-3 voxels of the finest axis (beyond 3 a
// needle's tunnel closes).
float coarse_sigma_mm(const volume::Volume& input, float grain_mm, float grains) {
  const float vox_mm = input.spacing_mm().minCoeff();
  return std::clamp(grains * grain_mm, 2.0f * vox_mm, 3.0f * vox_mm);
}

// The fine fit after the coarse retry: the image smoothed at this share of the first pass's
// sigma, and the wall fit with a reach and a move that span the coarse pre-filter's pull inward
// (2-3 voxels), averaged over more rings, since this image keeps more of the speckle.
constexpr float kFineFitSigmaFraction = 0.5f;
// (No probe apex: the along-beam crossing took the low-contrast retries' walls further in.)
const segment::WallFitOptions kFineFit{
    .reach_vox = 4.0f, .rings = 7, .max_move_vox = 3.0f, .probe_apex_mm = std::nullopt};

// Fits a coarse retry's surface to the wall on a finer image than the first pass's: the coarse
// pre-filter blurs the wall inward. Leaves `buffers.smoothed` holding that image.
void fine_fit(const volume::Volume& input, const PipelineConfig& config, float first_sigma_mm,
              PipelineBuffers& buffers, PipelineResult& result) {
  PipelineResult smoothed;
  smooth_again(input, result, kFineFitSigmaFraction * first_sigma_mm, buffers, smoothed);
  const auto t = Clock::now();
  result.mesh = segment::fit_to_wall(buffers.smoothed, result.mesh, result.balloon_stats, kFineFit,
                                     config.balloon.threads);
  result.topology.volume_ml = reconstruct::enclosed_volume_ml(result.mesh);
  result.enclosed_volume_ml = result.topology.volume_ml;
  result.timings.smooth_ms += smoothed.timings.smooth_ms;
  result.timings.reinflate_ms += ms_since(t);
}

// Whether `first`, suspect only for its low contrast, ended short of the wall the coarse retry's
// `other` found: `other` encloses more, though its pre-filter blurs the wall inward, and keeps the
// handles of a needle seen across it. (At contrast 0.3 the 64³ spheres' balloons crumple on the
// blood pool's speckle, 15-65 % small with speckle handles, which the retry's surfaces, 3-19 %
// small, do not have; where the retry encloses less it closed a torus's hole or a needle's
// tunnel, as the coarse pre-filter does to 64³ ones.)
bool short_of(const PipelineResult& first, const PipelineResult& other) {
  const bool needle_kept =
      !(first.shadow_voxels > 0 && other.topology.genus < first.topology.genus);
  return other.enclosed_volume_ml > first.enclosed_volume_ml && needle_kept;
}

// Whether the verdict will call `r` suspect from its balloon alone (balloon_reasons).
bool suspect_balloon(const volume::Volume& input, const Vec3f& seed_mm, const PipelineResult& r) {
  std::vector<std::string> why;
  balloon_reasons(input, seed_mm, r, why);
  return !why.empty();
}

}  // namespace

std::string segment_opinions(const volume::Volume& input, const Vec3f& seed_mm,
                             const PipelineConfig& config, PipelineBuffers& buffers,
                             const WarmStart* warm, const std::stop_token& stop, const Judge& judge,
                             PipelineResult& result, bool& judged,
                             const PipelineResult* known_target) {
  const PipelineResult smoothed_only = result;
  const bool switchable =
      config.second_opinion_level_stop > 0.0f && !(config.balloon.level_stop_fraction > 0.0f);
  // A warm start runs its previous result's rule. A cold start after a chain of the level stop's
  // runs it first too: Ψ_cost first stalled on the speckle at contrast 0.5, and the level stop
  // then ran as the second opinion. Without such a history, so does one in a probe's sector.
  const bool sector_first = !warm && !known_target && config.level_stop_first_in_sector &&
                            buffers.no_data.apex_mm && result.target == TargetPolarity::Dark;
  const bool level_first = switchable && (warm           ? warm->level_stop
                                          : known_target ? known_target->stop_rule == "level"
                                                         : sector_first);
  const PipelineConfig first_config = with_level_stop(config, level_first);
  std::string error = balloon_step(seed_mm, first_config, buffers, warm, stop, result);
  // A cold balloon the verdict calls suspect whatever its surface has that surface made only if
  // the second opinion is not ok: an ok one wins over it anyway.
  const bool later =
      switchable && error.empty() && !result.warm_start && suspect_balloon(input, seed_mm, result);
  if (error.empty() && !later)
    error = surface_steps(input, seed_mm, first_config, buffers, warm, stop, result);
  if (!switchable || error == "stopped" || result.warm_start) return error;
  if (!later) {
    judge(result, error);
    judged = true;
    // (At a pre-filter not the automatic one, as in the coarse retry, the blurred wall lies
    // within the open patch's samples: it is not asked.)
    if (result.ok && result.quality_ok &&
        (config.smooth_sigma_mm || known_target ||
         !(open_widely(buffers, config.balloon.threads, result) || thin(input, result))))
      return error;
  }
  PipelineResult other = smoothed_only;
  PipelineConfig other_config = with_level_stop(config, !level_first);
  // Against an ok first result a leak cannot win (sealed or rolled back, the verdict is suspect):
  // the other balloon ends at its first leak instead of sealing it (the 128³ cyst-needle's level
  // stop sealed 5 leaks along the needle's shadow in 1.4 s).
  if (!later && result.ok && result.quality_ok) other_config.balloon.max_leak_seals = 0;
  std::string other_error =
      segment_stages(input, seed_mm, other_config, buffers, nullptr, stop, other);
  result.second_opinion = true;
  if (other_error == "stopped") return later ? other_error : error;
  judge(other, other_error);
  other.second_opinion = true;
  other.start_reason = result.start_reason;  // (both cold: the first says why)
  const bool checked = !config.smooth_sigma_mm && !known_target;
  if (later) {
    if (other.ok && other.quality_ok) {
      // A level stop the sector put first that leaked says nothing against an ok Ψ_cost result,
      // as its leak says nothing when it is asked second (leaves_doubt): a real ventricle's base
      // opens onto the atrium, where the level stop leaks.
      const bool said_nothing =
          sector_first && (result.balloon_stats.leaked || result.balloon_stats.leak_seals > 0);
      if (checked && !said_nothing)
        confirm_in_place(input, buffers, config.balloon.threads, judge, other_error, other);
      judged = true;
      result = std::move(other);
      return other_error;
    }
    error = surface_steps(input, seed_mm, first_config, buffers, warm, stop, result);
    if (error == "stopped") return error;
    judge(result, error);
    judged = true;
  }
  if (!later && result.ok && result.quality_ok && !(other.ok && other.quality_ok) &&
      leaves_doubt(result, other)) {
    result.unconfirmed = true;
    judge(result, error);
  }
  // The level stop's ok result that the sector put first is what Ψ_cost first would have taken
  // in place of its suspect one: it is confirmed as that would be (a tube's stall).
  if (sector_first && checked && result.ok && result.quality_ok && !(other.ok && other.quality_ok))
    confirm_in_place(input, buffers, config.balloon.threads, judge, error, result);
  if (other.ok && other.quality_ok && result.quality_ok)
    open_widely(buffers, config.balloon.threads, other);
  else if (other.ok && other.quality_ok && checked)
    confirm_in_place(input, buffers, config.balloon.threads, judge, other_error, other);
  if (!better(other, result) && !deeper_of_two_closed(input, result, other)) return error;
  result = std::move(other);
  return other_error;
}

bool stalled_on_texture(const PipelineResult& r) {
  for (const std::string& why : r.quality_reasons)
    if (why == "stalled near the seed" || why == "implausibly small" ||
        why == "surface not on the target's wall" || why == "implausible genus")
      return true;
  return false;
}

bool wants_coarse_retry(const PipelineResult& r) {
  return stalled_on_texture(r) || std::find(r.quality_reasons.begin(), r.quality_reasons.end(),
                                            "low contrast") != r.quality_reasons.end();
}

void coarse_retry(const volume::Volume& input, const Vec3f& seed_mm, const PipelineConfig& config,
                  PipelineBuffers& buffers, const std::stop_token& stop, const Judge& judge,
                  PipelineResult& result, std::string& error) {
  PipelineConfig coarse = config;
  coarse.smooth_sigma_mm =
      coarse_sigma_mm(input, result.speckle_grain_mm, config.coarse_retry_grains);
  coarse.target = result.target;  // (decided once, by the first pass)
  // (Its wall lies where the fine fit takes it, not at the coarse image's volume.)
  coarse.fit_unsmoothed = false;
  PipelineResult other;
  smooth_again(input, result, *coarse.smooth_sigma_mm, buffers, other);
  bool judged = false;
  std::string other_error =
      segment_opinions(input, seed_mm, coarse, buffers, nullptr, stop, judge, other, judged);
  if (other_error == "stopped") return;
  other.coarse_retry = true;  // (after the second opinion's choice, which it would force)
  judge(other, other_error);
  other.timings.smooth_ms += result.timings.smooth_ms;
  if (!(stalled_on_texture(result)
            ? (other.ok && !stalled_on_texture(other)) || better(other, result)
            : better(other, result) && short_of(result, other)))
    return;
  if (config.wall_fit && other.ok && other.topology.manifold) {
    fine_fit(input, config, result.smooth_sigma_mm, buffers, other);
    judge(other, other_error);  // (the verdict's wall test now on the finer image)
  }
  result = std::move(other);
  error = std::move(other_error);
}

}  // namespace sonomesh::daemon::internal
