#include <CLI/CLI.hpp>
#include <filesystem>
#include <fstream>
#include <iomanip>
#include <iostream>
#include <memory>
#include <nlohmann/json.hpp>
#include <sstream>
#include <stdexcept>

#include "sim/internal/commands.h"
#include "sim/internal/shapes.h"
#include "sim/sim.h"

namespace sonomesh::sim::internal {
namespace {

struct GenerateArgs {
  PhantomSpec spec;
  std::string spacing = "0.5";
  std::string axis = "0,0,1";
  std::string needle_axis;
  std::string realism = "simple";
  bool speckle_given = false, attenuation_given = false;
  std::string out;
  std::string truth;
};

// "X" (isotropic) or "X,Y,Z".
Vec3f parse_vec3(const std::string& text, const char* option, bool allow_scalar) {
  std::vector<float> values;
  std::stringstream ss(text);
  std::string item;
  while (std::getline(ss, item, ',')) {
    try {
      std::size_t used = 0;
      values.push_back(std::stof(item, &used));
      if (used != item.size()) throw std::invalid_argument(item);
    } catch (const std::exception&) {
      throw std::invalid_argument(std::string(option) + ": '" + text + "' is not a number list");
    }
  }
  if (values.size() == 1 && allow_scalar) return Vec3f::Constant(values[0]);
  if (values.size() != 3)
    throw std::invalid_argument(std::string(option) + ": expected " +
                                (allow_scalar ? "X or X,Y,Z" : "X,Y,Z") + ", got '" + text + "'");
  return Vec3f(values[0], values[1], values[2]);
}

bool is_volume_path(const std::filesystem::path& p) {
  const std::string ext = p.extension().string();
  return ext == ".nrrd" || ext == ".nhdr" || ext == ".mha" || ext == ".mhd";
}

// Floats printed as the decimal a human typed (0.7, not 0.699999988).
double num(float v) {
  std::ostringstream text;
  text << std::setprecision(7) << v;  // a float has ~7 significant digits; print no more
  return std::stod(text.str());
}

nlohmann::json vec_json(const Vec3f& v) { return {num(v.x()), num(v.y()), num(v.z())}; }

void run_generate(GenerateArgs& args) {
  PhantomSpec& spec = args.spec;
  if (parse_realism(args.realism) == Realism::Echo) {
    // The echo preset's speckle and attenuation, unless given.
    const PhantomSpec preset = with_echo_realism(spec);
    spec.realism = Realism::Echo;
    if (!args.speckle_given) spec.speckle = preset.speckle;
    if (!args.attenuation_given) spec.attenuation_db_per_cm = preset.attenuation_db_per_cm;
  }
  spec.spacing_mm = parse_vec3(args.spacing, "--spacing", true);
  spec.axis = parse_vec3(args.axis, "--axis", false);
  if (!args.needle_axis.empty())
    spec.needle_axis = parse_vec3(args.needle_axis, "--needle-axis", false);
  const std::filesystem::path out(args.out), truth_path(args.truth);
  for (const auto& p : {out, truth_path})
    if (!is_volume_path(p))
      throw std::invalid_argument("'" + p.string() + "': use .nrrd, .nhdr, .mha or .mhd");
  if (std::filesystem::absolute(out) == std::filesystem::absolute(truth_path))
    throw std::invalid_argument("--out and --truth name the same file");

  const Phantom phantom = make_phantom(spec);
  if (auto err = volume::write_volume(phantom.image, out)) throw std::runtime_error(err->message);
  if (auto err = volume::write_volume(phantom.truth, truth_path))
    throw std::runtime_error(err->message);

  std::size_t target_voxels = 0;
  for (auto v : phantom.truth.u8()) target_voxels += v;
  const Vec3f h = phantom.image.spacing_mm();
  nlohmann::json j;
  j["phantom"] = phantom.name;
  j["genus"] = phantom.genus;
  j["seed_index"] = {phantom.seed_index.x(), phantom.seed_index.y(), phantom.seed_index.z()};
  j["seed_mm"] = vec_json(phantom.seed_mm);
  j["size"] = spec.size_vox;
  j["dims"] = {phantom.image.dims().x(), phantom.image.dims().y(), phantom.image.dims().z()};
  j["spacing_mm"] = vec_json(h);
  j["origin_mm"] = vec_json(phantom.image.origin_mm());
  j["seed"] = spec.seed;
  j["contrast"] = num(spec.contrast);
  j["speckle"] = num(spec.speckle);
  j["attenuation_db_per_cm"] = num(spec.attenuation_db_per_cm);
  j["time_s"] = num(spec.time_s);
  j["realism"] = to_string(spec.realism);
  if (spec.realism == Realism::Echo) j["speckle_mm"] = num(spec.speckle_mm);
  j["axis"] = vec_json(spec.axis);
  j["image"] = out.filename().string();
  j["truth"] = truth_path.filename().string();
  j["target_voxels"] = target_voxels;
  j["target_volume_ml"] = static_cast<double>(target_voxels) * h.x() * h.y() * h.z() / 1000.0;
  const Shape shape(spec, phantom.image.origin_mm());
  if (auto needle = shape.needle_at_time()) {
    j["needle_axis"] = vec_json(spec.needle_axis);
    j["needle"] = {{"point_mm", vec_json(needle->point_mm)},
                   {"direction", vec_json(needle->direction)},
                   {"tip_mm", vec_json(needle->point_mm + needle->direction * needle->tip_t_mm)},
                   {"radius_mm", num(needle->radius_mm)}};
  }
  std::filesystem::path sidecar = out;
  sidecar.replace_extension(".json");
  std::ofstream file(sidecar);
  file << j.dump(2) << '\n';
  file.close();
  if (!file) throw std::runtime_error("cannot write '" + sidecar.string() + "'");
}

}  // namespace

void add_generate_command(CLI::App& app, int& exit_code) {
  auto args = std::make_shared<GenerateArgs>();
  CLI::App* cmd =
      app.add_subcommand("generate", "Write one phantom volume, its truth labels and VOL.json");
  cmd->add_option("--phantom", args->spec.phantom, "Phantom")
      ->required()
      ->check(CLI::IsMember(phantom_names()));
  cmd->add_option("--size", args->spec.size_vox, "Edge of the cubic volume in voxels")
      ->capture_default_str();
  cmd->add_option("--seed", args->spec.seed, "Random seed (same seed, same bytes)")
      ->capture_default_str();
  cmd->add_option("--spacing", args->spacing, "Voxel spacing in mm: X or X,Y,Z")
      ->capture_default_str();
  cmd->add_option("--contrast", args->spec.contrast, "1 - target/tissue brightness, 0..1")
      ->capture_default_str();
  auto* speckle =
      cmd->add_option("--speckle", args->spec.speckle, "Speckle strength, 0..1 (echo: 1)")
          ->capture_default_str();
  auto* attenuation = cmd->add_option("--attenuation", args->spec.attenuation_db_per_cm,
                                      "Attenuation, dB/cm round trip (echo: 3)")
                          ->capture_default_str();
  cmd->add_option("--realism", args->realism,
                  "Image model: simple, or echo (a probe's sector view)")
      ->check(CLI::IsMember({"simple", "echo"}))
      ->capture_default_str();
  cmd->add_option("--speckle-mm", args->spec.speckle_mm, "Echo: speckle grain (lateral sigma), mm")
      ->capture_default_str();
  cmd->add_option("--time", args->spec.time_s, "Breathing time in s (0 = rest shape)")
      ->capture_default_str();
  cmd->add_option("--axis", args->axis, "Torus/ellipsoid/cyst axis X,Y,Z")->capture_default_str();
  cmd->add_option("--needle-axis", args->needle_axis, "Needle direction X,Y,Z (cyst-needle)");
  cmd->add_option("--needle-reach", args->spec.needle_reach,
                  "Needle reach (cyst-needle): 1 through the cyst, 0 tip in its middle")
      ->capture_default_str();
  cmd->add_option("--out", args->out, "Image volume (.nrrd, .nhdr, .mha, .mhd)")->required();
  cmd->add_option("--truth", args->truth, "Truth labels volume, inside = 1")->required();
  cmd->callback([args, speckle, attenuation, &exit_code] {
    try {
      args->speckle_given = speckle->count() > 0;
      args->attenuation_given = attenuation->count() > 0;
      run_generate(*args);
      exit_code = 0;
    } catch (const std::exception& e) {
      std::cerr << "probe-sim generate: " << e.what() << '\n';
      exit_code = 1;
    }
  });
}

}  // namespace sonomesh::sim::internal
