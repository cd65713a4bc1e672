// `sonomeshd process INPUT --seed-index I,J,K | --seed-mm X,Y,Z --mesh OUT.ply [--labels OUT.nrrd]
//  [--report OUT.json] [--balloon OUT.ply] [--vdb OUT.vdb] [--target dark|bright|auto]
//  [--config FILE.toml]`: one volume through the pipeline.
#include <unistd.h>

#include <array>
#include <cstdio>
#include <filesystem>
#include <map>
#include <memory>
#include <optional>
#include <sstream>
#include <string>
#include <vector>

#include "daemon/commands.h"
#include "daemon/internal/outputs.h"
#include "daemon/internal/run_config.h"
#include "daemon/pipeline.h"

namespace sonomesh::daemon {
namespace {

namespace fs = std::filesystem;

// Exit codes: 0 done, 1 the input or the computation failed, 2 bad arguments.
constexpr int kFailed = 1;
constexpr int kBadArguments = 2;

struct ProcessArgs {
  std::string input;
  std::string seed_index, seed_mm;
  std::string mesh, labels, report, balloon, vdb;
  std::string config;               // a run configuration whose pipeline tables apply (optional)
  bool labels_description = false;  // an ITK-SNAP label description beside the labels
  TargetPolarity target = TargetPolarity::Dark;
  bool target_given = false;  // --target overrides the configuration's pipeline.target
};

int fail(int code, const std::string& message) {
  std::fprintf(stderr, "sonomeshd process: %s\n", message.c_str());
  return code;
}

// "a,b,c" -> three numbers; nullopt on anything else (spaces around numbers are fine).
std::optional<std::array<double, 3>> parse_triple(const std::string& text) {
  std::array<double, 3> values{};
  std::stringstream stream(text);
  std::string part;
  int n = 0;
  while (std::getline(stream, part, ',')) {
    if (n == 3) return std::nullopt;
    try {
      std::size_t used = 0;
      values[n] = std::stod(part, &used);
      if (part.find_first_not_of(" \t", used) != std::string::npos) return std::nullopt;
    } catch (const std::exception&) {
      return std::nullopt;
    }
    ++n;
  }
  if (n != 3 || text.empty() || text.back() == ',') return std::nullopt;
  return values;
}

// Refuses an output whose directory is missing or not writable before any work is done.
std::optional<std::string> check_writable(const std::string& option, const std::string& path) {
  if (path.empty()) return std::nullopt;
  const fs::path parent = fs::absolute(fs::path(path)).parent_path();
  std::error_code ec;
  if (!fs::is_directory(parent, ec))
    return "cannot write " + option + " " + path + ": directory " + parent.string() +
           " does not exist";
  if (::access(parent.c_str(), W_OK) != 0)
    return "cannot write " + option + " " + path + ": directory " + parent.string() +
           " is not writable";
  if (fs::is_directory(fs::path(path), ec))
    return "cannot write " + option + " " + path + ": it is a directory";
  return std::nullopt;
}

// A suspect result is still written (DESIGN.md): one warning line, exit 0.
void warn_if_suspect(const ProcessArgs& args, const PipelineResult& result) {
  if (result.quality_ok) return;
  std::string reasons;
  for (const std::string& r : result.quality_reasons) reasons += (reasons.empty() ? "" : ", ") + r;
  std::fprintf(stderr, "sonomeshd process: warning: %s: result is suspect (%s)\n",
               args.input.c_str(), reasons.c_str());
}

// The mesh and the optional balloon, labels and indicator files; the first problem, if any.
std::optional<std::string> write_outputs(const ProcessArgs& args, const PipelineResult& result,
                                         const volume::Volume& input) {
  if (auto problem = internal::write_mesh_file(result.mesh, input, args.mesh)) return problem;
  if (!args.balloon.empty())
    if (auto problem =
            internal::write_balloon_ply(result.balloon, result.balloon_stop, input, args.balloon))
      return problem;
  if (!args.labels.empty() && result.labels)
    if (auto problem =
            internal::write_labels(*result.labels, input, args.labels, {args.labels_description}))
      return problem;
  if (!args.vdb.empty() && result.indicator)
    return internal::write_indicator_vdb(*result.indicator, args.vdb);
  return std::nullopt;
}

// The configuration file's pipeline tables (defaults without one); --target overrides its
// target.
std::optional<std::string> pipeline_config(const ProcessArgs& args, PipelineConfig& config) {
  RunConfig run_config;
  if (!args.config.empty())
    if (auto problem = load_config_file(args.config, run_config)) return problem;
  config = run_config.pipeline;
  if (args.target_given || args.config.empty()) config.target = args.target;
  return std::nullopt;
}

int run_process(const ProcessArgs& args) {
  if (args.seed_index.empty() == args.seed_mm.empty())
    return fail(kBadArguments, "give exactly one of --seed-index I,J,K and --seed-mm X,Y,Z");
  const std::string& seed_text = args.seed_index.empty() ? args.seed_mm : args.seed_index;
  const auto triple = parse_triple(seed_text);
  if (!triple)
    return fail(kBadArguments, std::string(args.seed_index.empty() ? "--seed-mm" : "--seed-index") +
                                   " expects three comma-separated numbers, got '" + seed_text +
                                   "'");
  if (!args.seed_index.empty())
    for (double v : *triple)
      if (v != static_cast<double>(static_cast<long long>(v)))
        return fail(kBadArguments,
                    "--seed-index expects integer voxel indices, got '" + seed_text + "'");
  const std::vector<std::pair<std::string, std::string>> outputs = {{"--mesh", args.mesh},
                                                                    {"--labels", args.labels},
                                                                    {"--report", args.report},
                                                                    {"--balloon", args.balloon},
                                                                    {"--vdb", args.vdb}};
  for (const auto& [option, path] : outputs)
    if (auto problem = check_writable(option, path)) return fail(kFailed, *problem);

  PipelineConfig config;
  if (auto problem = pipeline_config(args, config)) return fail(kBadArguments, *problem);
  auto read = volume::read_volume(args.input);
  if (!read) return fail(kFailed, read.error->message);
  const volume::Volume& input = read.volume;
  if (!read.note.empty())
    std::fprintf(stderr, "sonomeshd process: note: %s: %s\n", args.input.c_str(),
                 read.note.c_str());

  Vec3f seed_mm;
  if (!args.seed_index.empty()) {
    const Vec3i ijk((*triple)[0], (*triple)[1], (*triple)[2]);
    if (!input.contains_index(ijk)) {
      const Vec3i& d = input.dims();
      return fail(kFailed, "seed index (" + std::to_string(ijk.x()) + ", " +
                               std::to_string(ijk.y()) + ", " + std::to_string(ijk.z()) +
                               ") is outside the volume of " + std::to_string(d.x()) + "x" +
                               std::to_string(d.y()) + "x" + std::to_string(d.z()) + " voxels");
    }
    seed_mm = input.index_to_mm(ijk.cast<float>());
  } else {
    // --seed-mm is in the world frame (LPS mm); the pipeline runs in the grid frame.
    seed_mm =
        internal::seed_world_to_grid_mm(input, Vec3f((*triple)[0], (*triple)[1], (*triple)[2]));
  }
  if (auto problem = check_seed(input, seed_mm, config.target)) return fail(kFailed, *problem);

  config.want_labels = !args.labels.empty();  // (the report's deepest point comes from χ)
  config.track_max_chain = 0;                 // one volume: nothing to track
  config.want_indicator = !args.vdb.empty();
  const PipelineResult result = run_pipeline(input, seed_mm, config);

  // The report is written even when the pipeline failed: it says how far it got and why.
  if (!args.report.empty()) {
    if (auto problem = internal::write_text_atomically(
            args.report, report_json(result, args.input, input, seed_mm).dump(2) + "\n"))
      return fail(kFailed, *problem);
  }
  // So is the balloon, when there is one: it shows where a failed reconstruction began.
  if (!result.ok && !args.balloon.empty() && !result.balloon.triangles.empty())
    if (auto problem =
            internal::write_balloon_ply(result.balloon, result.balloon_stop, input, args.balloon))
      return fail(kFailed, *problem);
  if (!result.ok) return fail(kFailed, args.input + ": " + result.error);
  warn_if_suspect(args, result);
  if (auto problem = write_outputs(args, result, input)) return fail(kFailed, *problem);
  return 0;
}

}  // namespace

void add_process_command(CLI::App& app, int& exit_code) {
  auto args = std::make_shared<ProcessArgs>();
  CLI::App* cmd = app.add_subcommand(
      "process", "Segment one volume: smooth, balloon, reconstruct; write mesh, labels, report");
  cmd->add_option("input", args->input, "Input volume (.nrrd, .nhdr, .mha, .mhd, .nii, .nii.gz)")
      ->required();
  auto* by_index =
      cmd->add_option("--seed-index", args->seed_index, "Seed voxel I,J,K inside the target");
  auto* by_mm = cmd->add_option("--seed-mm", args->seed_mm, "Seed point X,Y,Z in mm");
  by_index->excludes(by_mm);
  cmd->add_option("--mesh", args->mesh, "Output surface in world LPS mm (.ply binary, .stl, .obj)")
      ->required();
  cmd->add_option("--labels", args->labels,
                  "Output label volume on the input grid (.nrrd, .nhdr, .mha, .mhd, .nii, .nii.gz, "
                  "or a 3D Slicer segmentation .seg.nrrd)");
  cmd->add_flag("--labels-description", args->labels_description,
                "Also write an ITK-SNAP label description (X.label.txt) beside the labels");
  cmd->add_option("--report", args->report, "Output report (JSON)");
  cmd->add_option("--balloon", args->balloon,
                  "Output balloon mesh with per-vertex stop reasons (PLY)");
  cmd->add_option("--vdb", args->vdb, "Output indicator function (OpenVDB)");
  cmd->add_option("--config", args->config,
                  "Run configuration (TOML); its [pipeline] tables apply, --target overrides");
  auto* target =
      cmd->add_option("--target", args->target, "Target polarity: dark (default), bright, auto");
  target->transform(CLI::CheckedTransformer(
      std::map<std::string, TargetPolarity>{{"dark", TargetPolarity::Dark},
                                            {"bright", TargetPolarity::Bright},
                                            {"auto", TargetPolarity::Auto}},
      CLI::ignore_case));
  cmd->callback([args, target, &exit_code] {
    args->target_given = target->count() > 0;
    exit_code = run_process(*args);
  });
}

}  // namespace sonomesh::daemon
