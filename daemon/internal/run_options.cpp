#include "daemon/internal/run_options.h"

#include <type_traits>

#include "daemon/internal/run_config.h"

namespace sonomesh::daemon {
namespace {

using reconstruct::DivergenceMode;
using K = OptionKind;

constexpr double kBig = 1e12;
// Ranges: closed [lo, hi] unless marked open.
constexpr OptionRange closed(double lo, double hi) { return {lo, hi, false, false}; }
constexpr OptionRange above(double lo, double hi) { return {lo, hi, true, false}; }
constexpr OptionRange open(double lo, double hi) { return {lo, hi, true, true}; }

template <typename Ref>
using Field = std::remove_reference_t<decltype(std::declval<Ref>()(std::declval<RunConfig&>()))>;

// A number field reached through `ref` (a lambda returning a reference into RunConfig).
template <typename Ref>
OptionSpec num(const char* table, const char* key, const char* unit, OptionRange range,
               const char* doc, Ref ref) {
  using T = Field<Ref>;
  return {
      table,
      key,
      std::is_integral_v<T> ? K::Integer : K::Number,
      unit,
      range,
      {},
      doc,
      [ref](const RunConfig& c) -> OptionValue {
        return static_cast<double>(ref(const_cast<RunConfig&>(c)));
      },
      [ref](RunConfig& c, const OptionValue& v) { ref(c) = static_cast<T>(std::get<double>(v)); }};
}

template <typename Ref>
OptionSpec flag(const char* table, const char* key, const char* doc, Ref ref) {
  return {table,
          key,
          K::Bool,
          "",
          {},
          {},
          doc,
          [ref](const RunConfig& c) -> OptionValue { return ref(const_cast<RunConfig&>(c)); },
          [ref](RunConfig& c, const OptionValue& v) { ref(c) = std::get<bool>(v); }};
}

template <typename Ref>
OptionSpec text(const char* table, const char* key, const char* doc, Ref ref) {
  return {table,
          key,
          K::String,
          "",
          {},
          {},
          doc,
          [ref](const RunConfig& c) -> OptionValue {
            return std::string(ref(const_cast<RunConfig&>(c)));
          },
          [ref](RunConfig& c, const OptionValue& v) { ref(c) = std::get<std::string>(v); }};
}

// A string out of `choices`, stored through `to`/`from` (an enum).
template <typename To, typename From>
OptionSpec choice(const char* table, const char* key, std::vector<std::string> choices,
                  const char* doc, To to, From from) {
  return {table,
          key,
          K::Choice,
          "",
          {},
          std::move(choices),
          doc,
          [from](const RunConfig& c) -> OptionValue { return std::string(from(c)); },
          [to](RunConfig& c, const OptionValue& v) { to(c, std::get<std::string>(v)); }};
}

#define REF(expr) \
  [](RunConfig & c) -> auto& { return c.expr; }

std::vector<OptionSpec> daemon_options() {
  std::vector<OptionSpec> o;
  o.push_back(text("daemon", "source", "SOURCE URI (sim:, replay:, unix:, tcp:, usb:, v4l2:)",
                   REF(source)));
  o.push_back(text("daemon", "out", "output directory (journal, meshes)", REF(out)));
  o.push_back({"daemon",
               "seed_mm",
               K::Triple,
               "mm",
               closed(-1e6, 1e6),
               {},
               "seed; unset: the sim: phantom's seed, else the volume centre",
               [](const RunConfig& c) -> OptionValue {
                 if (!c.seed_mm) return std::monostate{};
                 const auto& s = *c.seed_mm;
                 return std::array<double, 3>{s[0], s[1], s[2]};
               },
               [](RunConfig& c, const OptionValue& v) {
                 const auto& s = std::get<std::array<double, 3>>(v);
                 c.seed_mm = std::array<float, 3>{
                     static_cast<float>(s[0]), static_cast<float>(s[1]), static_cast<float>(s[2])};
               }});
  o.push_back(num("daemon", "queue_capacity", "volumes", closed(1, 64),
                  "volumes waiting for the worker", REF(queue_capacity)));
  o.push_back(num("daemon", "lanes", "volumes", closed(0, 2),
                  "segmented at once; 0: two for a live source on two cores", REF(lanes)));
  o.push_back(num("daemon", "heap_reserve_mb", "MB", closed(0, 512),
                  "heap touched at start-up, so the first volumes fault no pages; 0: off",
                  REF(heap_reserve_mb)));
  o.push_back(choice(
      "daemon", "log_level", {"trace", "debug", "info", "warn", "error", "critical", "off"},
      "log level", [](RunConfig& c, const std::string& s) { c.log_level = s; },
      [](const RunConfig& c) { return c.log_level; }));
  o.push_back({"http",
               "address",
               K::String,
               "",
               {},
               {},
               "HTTP status HOST:PORT; \"off\" disables",
               [](const RunConfig& c) -> OptionValue { return c.http_address; },
               [](RunConfig& c, const OptionValue& v) {
                 c.http_address = std::get<std::string>(v);
                 c.http_explicit = true;  // an address asked for must bind
               }});
  o.push_back(
      flag("http", "allow_remote", "allow a non-loopback HTTP address", REF(allow_remote_http)));
  return o;
}

std::vector<OptionSpec> source_and_output_options() {
  std::vector<OptionSpec> o;
  o.push_back(num("source", "rate_hz", "Hz", closed(0, 1000),
                  "replay pacing; 0: recorded timing or unpaced", REF(rate_hz)));
  o.push_back({"source",
               "max_dims",
               K::Triple,
               "voxels",
               closed(1, 65535),
               {},
               "largest volume accepted, per axis (whole numbers)",
               [](const RunConfig& c) -> OptionValue {
                 return std::array<double, 3>{double(c.max_dims[0]), double(c.max_dims[1]),
                                              double(c.max_dims[2])};
               },
               [](RunConfig& c, const OptionValue& v) {
                 const auto& d = std::get<std::array<double, 3>>(v);
                 for (int i = 0; i < 3; ++i) c.max_dims[i] = static_cast<int>(d[i]);
               }});
  o.push_back(num("source", "max_payload_bytes", "bytes", closed(1, 1ull << 40),
                  "largest record payload accepted", REF(max_payload_bytes)));
  o.push_back(
      text("source", "record_path", "tee good volumes to this .usv (\"\": off)", REF(record_path)));
  o.push_back(num("source", "connect_timeout_ms", "ms", closed(1, 600000), "socket connect timeout",
                  REF(connect_timeout_ms)));
  o.push_back(num("limits", "max_lost_lines", "lines", closed(0, kBig),
                  "a bigger sequence jump is an event, not N lines", REF(max_lost_lines)));
  o.push_back(num("limits", "keep_meshes", "meshes", closed(0, kBig),
                  "keep the newest N meshes and reports; 0 keeps all", REF(keep_meshes)));
  o.push_back(text("outputs", "igtl_listen",
                   "OpenIGTLink server ADDR:PORT for 3D Slicer (\"\": off)", REF(igtl_listen)));
  o.push_back(flag("outputs", "igtl_any_address", "allow a non-loopback igtl_listen",
                   REF(igtl_any_address)));
  return o;
}

std::vector<OptionSpec> pipeline_options() {
  std::vector<OptionSpec> o;
  o.push_back(choice(
      "pipeline", "target", {"dark", "bright", "auto"},
      "target darker or brighter than its surroundings, or decided from the seed region",
      [](RunConfig& c, const std::string& s) {
        c.pipeline.target = s == "bright" ? TargetPolarity::Bright
                            : s == "auto" ? TargetPolarity::Auto
                                          : TargetPolarity::Dark;
      },
      [](const RunConfig& c) { return std::string(to_string(c.pipeline.target)); }));
  o.push_back({"pipeline",
               "smooth_sigma_mm",
               K::NumberOrAuto,
               "mm",
               closed(0, 20),
               {},
               "pre-smoothing sigma; \"auto\": one voxel; 0: none",
               [](const RunConfig& c) -> OptionValue {
                 if (!c.pipeline.smooth_sigma_mm) return std::string("auto");
                 return static_cast<double>(*c.pipeline.smooth_sigma_mm);
               },
               [](RunConfig& c, const OptionValue& v) {
                 if (std::holds_alternative<double>(v)) {
                   c.pipeline.smooth_sigma_mm = static_cast<float>(std::get<double>(v));
                 } else {
                   c.pipeline.smooth_sigma_mm.reset();
                 }
               }});
  o.push_back(flag("pipeline", "reinflate", "second balloon pass, reconstruction to the wall",
                   REF(pipeline.reinflate)));
  o.push_back(num("pipeline", "reinflate_max_move_vox", "vox", above(0, 20),
                  "farthest a vertex moves in the second pass",
                  REF(pipeline.reinflate_pass.max_move_vox)));
  o.push_back(num("pipeline", "reinflate_max_iterations", "iterations", closed(1, 10000),
                  "second pass length", REF(pipeline.reinflate_pass.max_iterations)));
  o.push_back(flag("pipeline", "wall_fit", "vertices to the surface-averaged wall crossing",
                   REF(pipeline.wall_fit)));
  o.push_back(flag("pipeline", "fit_unsmoothed", "the wall fit again on the unsmoothed image",
                   REF(pipeline.fit_unsmoothed)));
  o.push_back(num("pipeline", "wall_fit_along_beam", "fraction", open(0, 1),
                  "how far up the rise a wall along a probe's beam is crossed (0.5: half way)",
                  REF(pipeline.wall_fit_options.along_beam_fraction)));
  o.push_back(flag("pipeline", "resurface", "rebuild the fitted surface", REF(pipeline.resurface)));
  o.push_back(flag("pipeline", "cell_from_voxel", "true: poisson.cell_mm = the finest spacing",
                   REF(pipeline.cell_from_voxel)));
  o.push_back(num("pipeline", "second_opinion_level_stop", "", closed(0, 0.99),
                  "level stop of the second try on a suspect result; 0: none",
                  REF(pipeline.second_opinion_level_stop)));
  o.push_back(flag("pipeline", "level_stop_first_in_sector",
                   "a cold start in a probe's sector tries the level stop first",
                   REF(pipeline.level_stop_first_in_sector)));
  o.push_back(num("pipeline", "coarse_retry_grains", "grains", closed(0, 10),
                  "pre-filter of the retry when both rules stalled; 0: none",
                  REF(pipeline.coarse_retry_grains)));
  o.push_back(flag("pipeline", "coarse_start",
                   "cold start on the volume halved, then to the wall at full resolution",
                   REF(pipeline.coarse_start)));
  o.push_back(num("pipeline", "coarse_start_inset_vox", "vox", closed(2, 20),
                  "how far inside the coarse balloon the full-resolution pass starts",
                  REF(pipeline.coarse_start_inset_vox)));
  o.push_back(num("pipeline", "coarse_start_min_vox", "vox", closed(8, 4096),
                  "least voxels per axis of a coarse grid", REF(pipeline.coarse_start_min_vox)));
  o.push_back(num("pipeline", "coarse_start_max_levels", "levels", closed(1, 4),
                  "halvings of the volume at most", REF(pipeline.coarse_start_max_levels)));
  o.push_back(flag("pipeline", "coarse_start_finest_when_needed",
                   "the full-resolution pass only where the coarse balloon cannot stand in",
                   REF(pipeline.coarse_start_finest_when_needed)));
  o.push_back(num("pipeline", "coarse_start_stand_in_min_vox", "vox", closed(8, 4096),
                  "least voxels per axis of a coarse grid whose balloon stands in",
                  REF(pipeline.coarse_start_stand_in_min_vox)));
  o.push_back(flag("pipeline", "shadow_gain", "lift a needle's shadow", REF(pipeline.shadow_gain)));
  o.push_back(num("pipeline", "track_max_chain", "volumes", closed(0, 1000),
                  "volumes in a row fitting the last surface", REF(pipeline.track_max_chain)));
  return o;
}

#define BAL(field) REF(pipeline.balloon.field)

std::vector<OptionSpec> balloon_options() {
  const char* t = "pipeline.balloon";
  std::vector<OptionSpec> o;
  o.push_back(num(t, "time_step", "", above(0, 10), "h per iteration", BAL(time_step)));
  o.push_back(
      num(t, "inflation_vox", "vox", above(0, 10), "mu, outward speed", BAL(inflation_vox)));
  o.push_back(num(t, "umbrella_weight", "", closed(0, 10), "lambda, smoothing to the neighbours",
                  BAL(umbrella_weight)));
  o.push_back(num(t, "initial_radius_vox", "vox", closed(1, 100), "radius of the first sphere",
                  BAL(initial_radius_vox)));
  o.push_back(flag(t, "relative_cost", "cost rises relative to the intensity they start from",
                   BAL(relative_cost)));
  o.push_back(num(t, "tau_cost", "", closed(0, 1e6), "boundary cost threshold; 0: from the image",
                  BAL(tau_cost)));
  o.push_back(num(t, "tau_cost_fraction", "", open(0, 1),
                  "with tau_cost 0: fraction of the target-to-tissue climb",
                  BAL(tau_cost_fraction)));
  o.push_back(num(t, "climb_backstop_fraction", "", above(0, 1),
                  "stop once the image rose this far to the tissue", BAL(climb_backstop_fraction)));
  o.push_back(num(t, "cost_window_vox", "vox", closed(0, 1e4),
                  "leak length of the cost; 0: the paper's plain sum", BAL(cost_window_vox)));
  o.push_back(flag(t, "rise_per_axis", "false: the paper's dot product", BAL(rise_per_axis)));
  o.push_back(flag(t, "noise_allowance", "threshold grows with the path", BAL(noise_allowance)));
  o.push_back(
      flag(t, "snap_to_wall", "a stopped vertex ends on the slope's peak", BAL(snap_to_wall)));
  o.push_back(num(t, "snap_back_vox", "vox", closed(0, 8), "snap window behind the stop",
                  BAL(snap_back_vox)));
  o.push_back(num(t, "snap_ahead_vox", "vox", closed(0, 8), "snap window ahead of the stop",
                  BAL(snap_ahead_vox)));
  o.push_back(num(t, "snap_min_slope", "per vox", closed(0, 10), "least <grad I, n> / I",
                  BAL(snap_min_slope)));
  o.push_back(num(t, "region_fraction", "", closed(0, 0.99),
                  "region term: move on while ahead looks inside; 0 off", BAL(region_fraction)));
  o.push_back(num(t, "level_stop_fraction", "", closed(0, 0.99),
                  "level stop: stop where the region ahead is the wall; 0 off",
                  BAL(level_stop_fraction)));
  o.push_back(num(t, "tau_curv", "", above(0, 2), "curvature stop threshold", BAL(tau_curv)));
  o.push_back(num(t, "self_intersection_cos", "", closed(-1, 1),
                  "cosine of the self-intersection test", BAL(self_intersection_cos)));
  o.push_back(num(t, "crumple_self_intersection_cos", "", closed(-1, 1),
                  "the test's cosine after a crumple; -1 off", BAL(crumple_self_intersection_cos)));
  o.push_back(num(t, "target_edge_vox", "vox", closed(0.25, 20), "remeshing edge length L",
                  BAL(target_edge_vox)));
  o.push_back(num(t, "remesh_every_iterations", "iterations", closed(1, 1000), "remeshing period",
                  BAL(remesh_every_iterations)));
  o.push_back(num(t, "max_iterations", "iterations", closed(1, 1e6), "iteration limit",
                  BAL(max_iterations)));
  o.push_back(num(t, "max_area_fraction", "", above(0, 100),
                  "leak bound, of the volume's bounding-box area", BAL(max_area_fraction)));
  o.push_back(num(t, "stall_window_iterations", "iterations", closed(1, 1e5), "stall test window",
                  BAL(stall_window_iterations)));
  o.push_back(num(t, "stall_motion_vox", "vox", closed(0, 10), "least motion over the window",
                  BAL(stall_motion_vox)));
  o.push_back(num(t, "swept_out_windows", "windows", closed(0, 1e4),
                  "end once A_t stops growing this long; 0 off", BAL(swept_out_windows)));
  o.push_back(
      flag(t, "open_folds", "a stopped vertex with swept space ahead is type 1", BAL(open_folds)));
  o.push_back(num(t, "threads", "threads", closed(0, 256), "0: the machine's cores", BAL(threads)));
  return o;
}

#define POI(field) REF(pipeline.poisson.field)

std::vector<OptionSpec> poisson_options() {
  const char* t = "pipeline.poisson";
  std::vector<OptionSpec> o;
  o.push_back(num(t, "cell_mm", "mm", closed(1e-3, 100), "grid cell (cell_from_voxel false)",
                  POI(cell_mm)));
  o.push_back(num(t, "padding_fraction", "", closed(0.1, 2), "margin per side, of the extent",
                  POI(padding_fraction)));
  o.push_back(num(t, "smoothing_cells", "cells", closed(0, 20), "normal splat sigma",
                  POI(smoothing_cells)));
  o.push_back(num(t, "min_feature_cells", "cells", closed(0, 16),
                  "a finer cell where a gap or solid is thinner; 0: off", POI(min_feature_cells)));
  o.push_back(num(t, "min_cell_fraction", "", closed(0.1, 1), "finest thin-feature cell",
                  POI(min_cell_fraction)));
  o.push_back(
      num(t, "max_grid_dim", "cells", closed(16, 2048), "largest grid axis", POI(max_grid_dim)));
  o.push_back(num(t, "fft_threads", "threads", closed(1, 256), "FFTW threads", POI(fft_threads)));
  o.push_back(choice(
      t, "divergence", {"spectral", "central-difference"}, "divergence operator",
      [](RunConfig& c, const std::string& s) {
        c.pipeline.poisson.divergence =
            s == "spectral" ? DivergenceMode::Spectral : DivergenceMode::CentralDifference;
      },
      [](const RunConfig& c) {
        return std::string(c.pipeline.poisson.divergence == DivergenceMode::Spectral
                               ? "spectral"
                               : "central-difference");
      }));
  o.push_back(flag(t, "measure_fft_plans", "FFTW_MEASURE plans", POI(measure_fft_plans)));
  return o;
}

}  // namespace

const std::vector<OptionSpec>& run_options() {
  static const std::vector<OptionSpec> table = [] {
    std::vector<OptionSpec> all;
    for (auto part : {daemon_options(), source_and_output_options(), pipeline_options(),
                      balloon_options(), poisson_options()})
      for (auto& spec : part) all.push_back(std::move(spec));
    return all;
  }();
  return table;
}

const OptionSpec* find_option(const std::string& table, const std::string& key) {
  for (const OptionSpec& spec : run_options())
    if (table == spec.table && key == spec.key) return &spec;
  return nullptr;
}

}  // namespace sonomesh::daemon
