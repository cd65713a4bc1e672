// accuracy_report: one phantom through the pipeline, compared with its ground truth.
//   accuracy_report --phantom NAME [--size N] [--spacing MM] [--speckle S] [--contrast C]
//                   [--seed N] [--time S] [--needle-reach R] [--repeat N]
//                   [--realism simple|echo] [--format md|json] [--jsonl ROWS.jsonl]
//   accuracy_report --header
//   accuracy_report --summarize ROWS.jsonl
// Prints one markdown table row (the header with --header) or one JSON object; --jsonl also
// appends the JSON row to a file, which --summarize turns into one summary row per realism mode and
// contrast. Distances are in voxels: Dice and the boundary distances of daemon/internal/metrics.h
// between the result's label volume and the truth. "balloon Dice" rasterizes the balloon itself,
// which tells whether accuracy is lost in the first step (balloon) or the second (opening +
// reconstruction). Volume error compares the mesh's enclosed volume with the truth's voxels.
// "wall_offset_vox": the result's vertices' mean signed distance from the truth's wall (outside
// positive), and in a probe's sector apart for those facing the probe and those whose wall runs
// along the beam (docs/stopping.md item 13); --summarize gives the last two's means.
// "balloon_offset_vox": the same for the first balloon, before the steps that place the wall.
#include <CLI/CLI.hpp>
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <fstream>
#include <map>
#include <nlohmann/json.hpp>
#include <string>
#include <vector>

#include "daemon/internal/metrics.h"
#include "daemon/internal/run_config.h"
#include "daemon/internal/shadow_gain.h"
#include "daemon/internal/target_image.h"
#include "daemon/pipeline.h"
#include "mesh/mesh.h"
#include "sim/sim.h"

namespace {

using namespace sonomesh;
using nlohmann::json;

double median(std::vector<double> values) {
  if (values.empty()) return std::nan("");
  std::sort(values.begin(), values.end());
  return values[values.size() / 2];
}

std::string joined(const std::vector<std::string>& items) {
  std::string out;
  for (const auto& s : items) out += (out.empty() ? "" : "; ") + s;
  return out;
}

// The truth's signed distance in voxels, negative inside, its wall half way between an inside
// voxel's centre and an outside one's.
volume::Volume signed_distance_vox(const volume::Volume& truth) {
  const std::vector<std::uint8_t>& t = truth.u8();
  std::vector<bool> inside(t.size()), outside(t.size());
  for (std::size_t i = 0; i < t.size(); ++i) inside[i] = t[i] != 0, outside[i] = t[i] == 0;
  const volume::Vec3f unit = volume::Vec3f::Ones();
  const auto to_inside =
      daemon::internal::squared_distance_transform_mm2(inside, truth.dims(), unit);
  const auto to_outside =
      daemon::internal::squared_distance_transform_mm2(outside, truth.dims(), unit);
  volume::Volume sd(truth.dims(), truth.spacing_mm(), truth.origin_mm(),
                    volume::VoxelType::Float32);
  std::vector<float>& v = sd.f32();
  for (std::size_t i = 0; i < t.size(); ++i)
    v[i] = inside[i] ? 0.5f - std::sqrt(to_outside[i]) : std::sqrt(to_inside[i]) - 0.5f;
  return sd;
}

// The surface's vertices' mean signed distance `sd` (signed_distance_vox) from the truth's wall,
// all of them and, where the image is a probe's sector, those facing its apex and those along its
// beams.
json wall_offsets(const sim::Phantom& phantom, const volume::Volume& sd,
                  const segment::Mesh& surface) {
  if (surface.vertices.empty()) return nullptr;
  const std::optional<volume::Vec3f> apex = daemon::internal::sector_apex_mm(
      phantom.image, daemon::internal::no_data_mask(phantom.image));
  const std::vector<volume::Vec3f> normal = mesh::vertex_normals(surface);
  double sum[3] = {0, 0, 0};
  int count[3] = {0, 0, 0};  // all, facing, along the beam
  for (std::size_t v = 0; v < surface.vertices.size(); ++v) {
    const double d = volume::sample_mm(sd, surface.vertices[v]);
    sum[0] += d, ++count[0];
    if (!apex) continue;
    const int k = segment::faces_probe(surface.vertices[v], normal[v], *apex) ? 1 : 2;
    sum[k] += d, ++count[k];
  }
  const auto mean = [&](int k) { return count[k] ? json(sum[k] / count[k]) : json(nullptr); };
  return {{"all", mean(0)}, {"facing", mean(1)}, {"along_beam", mean(2)}};
}

void print_header() {
  std::printf(
      "| phantom | size | speckle | contrast | Dice | balloon Dice | result/truth volume | MSD "
      "(vox) | HD95 (vox) "
      "| genus expected | genus found | watertight | components | total ms (median) "
      "| balloon stops B/C/S/I | volume error | quality | stop rule |\n");
  std::printf("|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|\n");
}

// One case: the pipeline `repeat` times on the phantom, from its seed moved by `seed_offset`
// times the radius of the ball of the target's volume; the last result measured.
json measure(const sim::PhantomSpec& spec, const daemon::RunConfig& config, int repeat,
             const volume::Vec3f& seed_offset) {
  const sim::Phantom phantom = sim::make_phantom(spec);
  const float radius_mm = static_cast<float>(daemon::internal::equivalent_radius_mm(phantom.truth));
  const volume::Vec3f seed_mm = phantom.seed_mm + radius_mm * seed_offset;
  daemon::PipelineResult result;
  std::vector<double> totals;
  for (int r = 0; r < repeat; ++r) {
    result = daemon::run_pipeline(phantom.image, seed_mm, config.pipeline);
    totals.push_back(result.timings.total_ms);
  }
  json row = {{"phantom", spec.phantom},
              {"realism", sim::to_string(spec.realism)},
              {"size", spec.size_vox},
              {"seed", spec.seed},
              {"time_s", spec.time_s},
              {"needle_reach", spec.needle_reach},
              {"spacing_mm", spec.spacing_mm.x()},
              {"seed_offset", {seed_offset.x(), seed_offset.y(), seed_offset.z()}},
              {"speckle", spec.speckle},
              {"contrast", spec.contrast},
              {"genus_expected", phantom.genus},
              {"ok", result.ok},
              {"error", result.error},
              {"total_ms", median(totals)}};
  double dice = 0, balloon_dice = 0, volume_ratio = 0, volume_error = 0;
  daemon::internal::SurfaceDistances distances;
  std::size_t truth_voxels = 0;
  for (std::uint8_t v : phantom.truth.u8()) truth_voxels += v != 0;
  const volume::Vec3f h = phantom.truth.spacing_mm();
  const double truth_ml = static_cast<double>(truth_voxels) * h.x() * h.y() * h.z() / 1000.0;
  if (result.ok && result.labels) {
    dice = daemon::internal::dice(*result.labels, phantom.truth);
    distances = daemon::internal::surface_distances(*result.labels, phantom.truth);
    std::size_t found = 0;
    for (std::uint8_t v : result.labels->u8()) found += v != 0;
    volume_ratio =
        truth_voxels ? static_cast<double>(found) / static_cast<double>(truth_voxels) : 0.0;
    volume_error = truth_ml > 0 ? result.enclosed_volume_ml / truth_ml - 1.0 : 0.0;
  }
  if (!result.balloon.triangles.empty())
    balloon_dice = daemon::internal::dice(
        reconstruct::rasterize_labels(result.balloon, phantom.image), phantom.truth);
  const auto& s = result.stop_counts;
  const volume::Volume sd = signed_distance_vox(phantom.truth);
  row.update(
      {{"dice", dice},
       {"balloon_dice", balloon_dice},
       {"volume_ratio", volume_ratio},
       {"volume_error", volume_error},
       {"msd_vox", distances.mean_vox},
       {"hd95_vox", distances.hd95_vox},
       {"wall_offset_vox", result.ok ? wall_offsets(phantom, sd, result.mesh) : json(nullptr)},
       {"balloon_offset_vox",
        result.ok ? wall_offsets(phantom, sd, result.balloon) : json(nullptr)},
       {"genus_found", result.topology.genus},
       {"watertight", result.topology.watertight},
       {"components", result.topology.components},
       {"quality", result.quality_ok ? "ok" : "suspect"},
       {"quality_reasons", result.quality_reasons},
       {"wall_support", result.wall_support},
       {"open_patch", result.open_patch},
       {"seed_level", result.balloon_stats.seed_level},
       {"tissue_level", result.balloon_stats.tissue_level},
       {"seed_sigma", result.balloon_stats.seed_sigma},
       {"speckle_grain_mm", result.speckle_grain_mm},
       {"smooth_sigma_mm", result.smooth_sigma_mm},
       {"deepest_depth_mm", result.deepest_depth_mm},
       {"stop_rule", result.stop_rule},
       {"second_opinion", result.second_opinion},
       {"stops", {s.boundary, s.curvature, s.self_intersection, s.iteration_limit}}});
  return row;
}

// "cost" or "level", and whether the pipeline's second opinion ran ("tried") or gave the result.
std::string stop_rule(const json& r) {
  const std::string rule = r.value("stop_rule", "");
  if (!r.value("second_opinion", false)) return rule;
  return rule == "level" ? "level (second opinion)" : rule + " (second opinion tried)";
}

void print_row(const json& r) {
  std::string name = r["phantom"].get<std::string>();
  if (r.value("needle_reach", 1.0) != 1.0 && name == "cyst-needle") {
    char reach[32];
    std::snprintf(reach, sizeof reach, " reach %.1f", r["needle_reach"].get<double>());
    name += reach;
  }
  if (r["realism"] != "simple") name += " (" + r["realism"].get<std::string>() + ")";
  const std::string quality =
      r["quality"] == "ok"
          ? "ok"
          : "suspect: " + joined(r["quality_reasons"].get<std::vector<std::string>>());
  if (!r["ok"].get<bool>()) {
    std::printf(
        "| %s | %d | %.2f | %.2f | failed: %s |  |  |  |  | %d |  |  |  | %.1f |  |  |  |  |\n",
        name.c_str(), r["size"].get<int>(), r["speckle"].get<double>(), r["contrast"].get<double>(),
        r["error"].get<std::string>().c_str(), r["genus_expected"].get<int>(),
        r["total_ms"].get<double>());
    return;
  }
  const auto& s = r["stops"];
  std::printf(
      "| %s | %d | %.2f | %.2f | %.3f | %.3f | %.3f | %.2f | %.2f | %d | %d | %s | %d | %.1f "
      "| %d/%d/%d/%d | %+.1f %% | %s | %s |\n",
      name.c_str(), r["size"].get<int>(), r["speckle"].get<double>(), r["contrast"].get<double>(),
      r["dice"].get<double>(), r["balloon_dice"].get<double>(), r["volume_ratio"].get<double>(),
      r["msd_vox"].get<double>(), r["hd95_vox"].get<double>(), r["genus_expected"].get<int>(),
      r["genus_found"].get<int>(), r["watertight"].get<bool>() ? "yes" : "no",
      r["components"].get<int>(), r["total_ms"].get<double>(), s[0].get<int>(), s[1].get<int>(),
      s[2].get<int>(), s[3].get<int>(), 100.0 * r["volume_error"].get<double>(), quality.c_str(),
      stop_rule(r).c_str());
}

// A result under this Dice is wrong whatever its genus (docs/results.md's "wrong and ok").
constexpr double kRightDice = 0.9;

// One row per (realism, contrast): how many cases and how many failed, Dice median and worst (a
// failed case counts as 0), over the cases with a surface: mean MSD, worst HD95, |volume error|
// median and worst; genus right and quality ok out of all cases, and the wrong results called ok
// (genus wrong or Dice under kRightDice): the verdict's misses.
// The rows' mean wall offsets "facing / along the beam" in voxels (wall_offsets), "-" without a
// probe's sector.
std::string mean_wall_offsets(const std::vector<json>& rows) {
  double sum[2] = {0, 0};
  int count = 0;
  for (const json& r : rows) {
    const json& w = r.value("wall_offset_vox", json(nullptr));
    if (!w.is_object() || w["facing"].is_null() || w["along_beam"].is_null()) continue;
    sum[0] += w["facing"].get<double>(), sum[1] += w["along_beam"].get<double>(), ++count;
  }
  if (count == 0) return "-";
  char text[64];
  std::snprintf(text, sizeof text, "%+.2f / %+.2f", sum[0] / count, sum[1] / count);
  return text;
}

int summarize(const std::string& path) {
  std::ifstream in(path);
  if (!in) {
    std::fprintf(stderr, "accuracy_report: cannot read '%s'\n", path.c_str());
    return 2;
  }
  std::map<std::pair<std::string, double>, std::vector<json>> groups;
  std::string line;
  for (int n = 1; std::getline(in, line); ++n) {
    if (line.empty()) continue;
    const json r = json::parse(line, nullptr, false);
    if (r.is_discarded() || !r.contains("contrast") || !r.contains("dice")) {
      std::fprintf(stderr, "accuracy_report: %s:%d is not an accuracy row\n", path.c_str(), n);
      return 2;
    }
    const double c = std::round(r["contrast"].get<double>() * 100.0) / 100.0;
    groups[{r.value("realism", "simple"), c}].push_back(r);
  }
  std::printf(
      "| realism | contrast | cases | failed | Dice median | Dice min | MSD mean (vox) | HD95 max "
      "(vox) "
      "| genus right | abs volume error median | abs volume error max | quality ok | wrong and ok "
      "| wall offset facing / along the beam (vox) |\n");
  std::printf("|---|---|---|---|---|---|---|---|---|---|---|---|---|---|\n");
  for (const auto& [key, rows] : groups) {
    std::vector<double> dice, err, msd;
    double hd95 = 0;
    int genus_right = 0, quality_ok = 0, failed = 0, wrong_ok = 0;
    for (const json& r : rows) {
      const bool ok = r["ok"].get<bool>();
      dice.push_back(ok ? r["dice"].get<double>() : 0.0);
      failed += !ok;
      if (!ok) continue;  // distances and volumes only exist for a surface
      err.push_back(std::abs(r["volume_error"].get<double>()));
      msd.push_back(r["msd_vox"].get<double>());
      hd95 = std::max(hd95, r["hd95_vox"].get<double>());
      const bool right = r["genus_found"] == r["genus_expected"];
      const bool called_ok = r.value("quality", "ok") == "ok";
      genus_right += right;
      quality_ok += called_ok;
      wrong_ok += called_ok && (!right || r["dice"].get<double>() < kRightDice);
    }
    double msd_mean = 0;
    for (double m : msd) msd_mean += m / static_cast<double>(msd.size());
    const double err_max = err.empty() ? std::nan("") : *std::max_element(err.begin(), err.end());
    std::printf(
        "| %s | %.2f | %zu | %d | %.3f | %.3f | %.2f | %.2f | %d/%zu | %.1f %% | %.1f %% | %d/%zu "
        "| %d | %s |\n",
        key.first.c_str(), key.second, rows.size(), failed, median(dice),
        *std::min_element(dice.begin(), dice.end()), msd.empty() ? std::nan("") : msd_mean, hd95,
        genus_right, rows.size(), 100.0 * median(err), 100.0 * err_max, quality_ok, rows.size(),
        wrong_ok, mean_wall_offsets(rows).c_str());
  }
  return 0;
}

}  // namespace

int main(int argc, char** argv) {
  CLI::App app{"accuracy_report: pipeline result vs phantom ground truth"};
  sim::PhantomSpec spec;
  int repeat = 3;
  std::string format = "md", realism = "simple", jsonl, summary, config_path;
  bool header = false;
  app.add_option("--phantom", spec.phantom,
                 "sphere, ellipsoid, torus, cyst-needle, double-torus, lv");
  app.add_option("--size", spec.size_vox, "Edge of the cubic volume (voxels)");
  auto* speckle =
      app.add_option("--speckle", spec.speckle, "Speckle strength (0 = none; echo default 1)");
  app.add_option("--contrast", spec.contrast, "Target contrast (0..1)");
  app.add_option("--seed", spec.seed, "Random seed");
  app.add_option("--time", spec.time_s, "Breathing phase (s)");
  app.add_option("--needle-reach", spec.needle_reach,
                 "Cyst-needle: 1 through the cyst, 0 its tip in the middle")
      ->check(CLI::Range(-1.0f, 1.0f));
  float spacing_mm = 0.0f;
  app.add_option("--spacing", spacing_mm, "Voxel spacing in mm (default: the phantom's)")
      ->check(CLI::PositiveNumber);
  std::vector<float> offset{0.0f, 0.0f, 0.0f};
  app.add_option("--seed-offset", offset,
                 "X Y Z: the seed moved by this much of the target's equivalent radius")
      ->expected(3);
  app.add_option("--realism", realism, "Image model: simple or echo (sim::with_echo_realism)")
      ->check(CLI::IsMember({"simple", "echo"}));
  app.add_option("--repeat", repeat, "Runs per case; the median time is reported")
      ->check(CLI::Range(1, 100));
  app.add_option("--format", format, "md or json")->check(CLI::IsMember({"md", "json"}));
  app.add_option("--jsonl", jsonl, "Also append the JSON row to this file");
  app.add_option("--summarize", summary,
                 "Print the per-contrast summary of a --jsonl file and exit");
  app.add_option("--config", config_path,
                 "TOML file as sonomeshd run reads it; its [pipeline] tables set the options");
  app.add_flag("--header", header, "Print the markdown table header and exit");
  try {
    app.parse(argc, argv);
  } catch (const CLI::CallForHelp& e) {
    return app.exit(e);
  } catch (const CLI::ParseError& e) {
    std::fprintf(stderr, "accuracy_report: %s\n", e.what());
    return 2;
  }
  if (header) {
    print_header();
    return 0;
  }
  if (!summary.empty()) return summarize(summary);
  try {
    daemon::RunConfig config;
    if (!config_path.empty()) {
      if (auto error = daemon::load_config_file(config_path, config)) {
        std::fprintf(stderr, "accuracy_report: %s\n", error->c_str());
        return 2;
      }
    }
    if (spacing_mm > 0.0f) spec.spacing_mm = volume::Vec3f::Constant(spacing_mm);
    if (realism == "echo") {  // the preset's speckle and attenuation, unless --speckle is given
      const float given = spec.speckle;
      spec = sim::with_echo_realism(spec);
      if (speckle->count() > 0) spec.speckle = given;
    }
    const json row = measure(spec, config, repeat, volume::Vec3f(offset[0], offset[1], offset[2]));
    if (format == "json")
      std::printf("%s\n", row.dump().c_str());
    else
      print_row(row);
    if (!jsonl.empty()) {
      std::ofstream out(jsonl, std::ios::app);
      out << row.dump() << '\n';
      if (!out) throw std::runtime_error("cannot append to '" + jsonl + "'");
    }
    return 0;
  } catch (const std::exception& e) {
    std::fprintf(stderr, "accuracy_report: %s\n", e.what());
    return 1;
  }
}
