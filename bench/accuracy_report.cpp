// accuracy_report: one phantom through the pipeline, compared with its ground truth.
//   accuracy_report --phantom NAME [--size N] [--speckle S] [--contrast C] [--seed N] [--repeat N]
//                   [--format md|json]
// Prints one markdown table row (the header with --header) or one JSON object. Distances are in
// voxels: Dice and the boundary distances of daemon/internal/metrics.h between the result's label
// volume and the truth. "balloon Dice" rasterizes the balloon itself, which tells whether accuracy
// is lost in the first step (balloon) or the second (opening + reconstruction).
#include <CLI/CLI.hpp>
#include <algorithm>
#include <cstdio>
#include <nlohmann/json.hpp>
#include <string>
#include <vector>

#include "daemon/internal/metrics.h"
#include "daemon/internal/run_config.h"
#include "daemon/pipeline.h"
#include "sim/sim.h"

namespace {

using namespace sonomesh;

double median(std::vector<double> values) {
  std::sort(values.begin(), values.end());
  return values[values.size() / 2];
}

}  // namespace

int main(int argc, char** argv) {
  CLI::App app{"accuracy_report: pipeline result vs phantom ground truth"};
  sim::PhantomSpec spec;
  int repeat = 3;
  std::string format = "md";
  bool header = false;
  app.add_option("--phantom", spec.phantom, "sphere, ellipsoid, torus, cyst-needle, double-torus");
  app.add_option("--size", spec.size_vox, "Edge of the cubic volume (voxels)");
  app.add_option("--speckle", spec.speckle, "Speckle strength (0 = none)");
  app.add_option("--contrast", spec.contrast, "Target contrast (0..1)");
  app.add_option("--seed", spec.seed, "Random seed");
  app.add_option("--repeat", repeat, "Runs per case; the median time is reported")
      ->check(CLI::Range(1, 100));
  app.add_option("--format", format, "md or json")->check(CLI::IsMember({"md", "json"}));
  std::string config_path;
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
    std::printf("| phantom | size | speckle | contrast | Dice | balloon Dice | result/truth volume | MSD (vox) | HD95 (vox) "
                "| genus expected | genus found | watertight | components | total ms (median) "
                "| balloon stops B/C/S/I |\n");
    std::printf("|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|\n");
    return 0;
  }
  try {
    daemon::RunConfig config;
    if (!config_path.empty()) {
      if (auto error = daemon::load_config_file(config_path, config)) {
        std::fprintf(stderr, "accuracy_report: %s\n", error->c_str());
        return 2;
      }
    }
    const sim::Phantom phantom = sim::make_phantom(spec);
    daemon::PipelineResult result;
    std::vector<double> totals;
    for (int r = 0; r < repeat; ++r) {
      result = daemon::run_pipeline(phantom.image, phantom.seed_mm, config.pipeline);
      totals.push_back(result.timings.total_ms);
    }
    nlohmann::json row = {{"phantom", spec.phantom},   {"size", spec.size_vox},
                          {"speckle", spec.speckle},   {"contrast", spec.contrast},
                          {"genus_expected", phantom.genus}, {"ok", result.ok},
                          {"error", result.error}};
    double dice = 0, balloon_dice = 0, volume_ratio = 0;
    daemon::internal::SurfaceDistances distances;
    if (result.ok && result.labels) {
      dice = daemon::internal::dice(*result.labels, phantom.truth);
      distances = daemon::internal::surface_distances(*result.labels, phantom.truth);
      std::size_t found = 0, truth = 0;
      for (std::uint8_t v : result.labels->u8()) found += v != 0;
      for (std::uint8_t v : phantom.truth.u8()) truth += v != 0;
      volume_ratio = truth ? static_cast<double>(found) / static_cast<double>(truth) : 0.0;
    }
    if (!result.balloon.triangles.empty())
      balloon_dice = daemon::internal::dice(
          reconstruct::rasterize_labels(result.balloon, phantom.image), phantom.truth);
    const auto& s = result.stop_counts;
    row.update({{"dice", dice},
                {"balloon_dice", balloon_dice},
                {"volume_ratio", volume_ratio},
                {"msd_vox", distances.mean_vox},
                {"hd95_vox", distances.hd95_vox},
                {"genus_found", result.topology.genus},
                {"watertight", result.topology.watertight},
                {"components", result.topology.components},
                {"total_ms", median(totals)},
                {"stops", {s.boundary, s.curvature, s.self_intersection, s.iteration_limit}}});
    if (format == "json") {
      std::printf("%s\n", row.dump().c_str());
    } else if (!result.ok) {
      std::printf("| %s | %d | %.2f | %.2f | failed: %s |  |  |  |  | %d |  |  |  | %.1f |  |\n",
                  spec.phantom.c_str(), spec.size_vox, spec.speckle, spec.contrast,
                  result.error.c_str(), phantom.genus, median(totals));
    } else {
      std::printf("| %s | %d | %.2f | %.2f | %.3f | %.3f | %.3f | %.2f | %.2f | %d | %d | %s | %d | %.1f "
                  "| %d/%d/%d/%d |\n",
                  spec.phantom.c_str(), spec.size_vox, spec.speckle, spec.contrast, dice,
                  balloon_dice, volume_ratio, distances.mean_vox, distances.hd95_vox, phantom.genus,
                  result.topology.genus, result.topology.watertight ? "yes" : "no",
                  result.topology.components, median(totals), s.boundary, s.curvature,
                  s.self_intersection, s.iteration_limit);
    }
    return 0;
  } catch (const std::exception& e) {
    std::fprintf(stderr, "accuracy_report: %s\n", e.what());
    return 1;
  }
}
