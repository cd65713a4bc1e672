#include "daemon/internal/run_config.h"

#include <cmath>
#include <cstdio>
#include <fstream>
#include <set>
#include <sstream>

#include <toml++/toml.h>

#include "daemon/internal/http_status.h"

namespace sonomesh::daemon {

namespace {

using reconstruct::DivergenceMode;

// Reads typed values out of one TOML table and refuses keys nobody reads (a typo in a key must
// not be silently ignored in a clinical setting).
class TableReader {
 public:
  TableReader(const toml::table* table, std::string name, std::string origin)
      : table_(table), name_(std::move(name)), origin_(std::move(origin)) {}

  template <typename T>
  void number(const char* key, T& out, double lo, double hi) {
    const toml::node* node = find(key);
    if (!node) return;
    double v = 0;
    if (auto i = node->value_exact<std::int64_t>()) {
      v = static_cast<double>(*i);
    } else if (auto f = node->value_exact<double>()) {
      v = *f;
    } else {
      return fail(key, "must be a number");
    }
    if (!(v >= lo && v <= hi)) {
      return fail(key, "must be in [" + fmt(lo) + ", " + fmt(hi) + "], got " + fmt(v));
    }
    if constexpr (std::is_integral_v<T>) {
      if (v != std::floor(v)) return fail(key, "must be a whole number");
    }
    out = static_cast<T>(v);
  }
  void boolean(const char* key, bool& out) {
    const toml::node* node = find(key);
    if (!node) return;
    if (auto b = node->value_exact<bool>()) {
      out = *b;
    } else {
      fail(key, "must be true or false");
    }
  }
  void string(const char* key, std::string& out) {
    const toml::node* node = find(key);
    if (!node) return;
    if (auto s = node->value_exact<std::string>()) {
      out = *s;
    } else {
      fail(key, "must be a string");
    }
  }
  // An array of three numbers.
  bool triple(const char* key, std::array<double, 3>& out) {
    const toml::node* node = find(key);
    if (!node) return false;
    const toml::array* arr = node->as_array();
    if (!arr || arr->size() != 3) {
      fail(key, "must be an array of three numbers");
      return false;
    }
    for (std::size_t i = 0; i < 3; ++i) {
      const toml::node& n = *arr->get(i);
      if (auto v = n.value<double>()) {
        out[i] = *v;
      } else {
        fail(key, "must be an array of three numbers");
        return false;
      }
      if (!std::isfinite(out[i])) {
        fail(key, "must be finite");
        return false;
      }
    }
    return true;
  }
  const toml::node* raw(const char* key) { return find(key); }

  // Call after reading: reports keys that nothing read.
  void finish(const std::set<std::string>& subtables = {}) {
    if (!table_) return;
    for (const auto& [key, node] : *table_) {
      const std::string k(key.str());
      if (!read_.count(k) && !subtables.count(k)) {
        fail(k.c_str(), "is not a known option");
      }
    }
  }
  void fail(const char* key, const std::string& what) {
    if (!error.empty()) return;
    error = origin_ + ": " + (name_.empty() ? std::string() : name_ + ".") + key + " " + what;
  }

  std::string error;

 private:
  const toml::node* find(const char* key) {
    read_.insert(key);
    if (!table_) return nullptr;
    return table_->get(key);
  }
  static std::string fmt(double v) {
    std::ostringstream out;
    out << v;
    return out.str();
  }

  const toml::table* table_;
  std::string name_;
  std::string origin_;
  std::set<std::string> read_;
};

const toml::table* subtable(const toml::table& root, const char* key, std::string& error,
                            const std::string& origin) {
  const toml::node* node = root.get(key);
  if (!node) return nullptr;
  if (!node->is_table()) {
    if (error.empty()) error = origin + ": [" + key + "] must be a table";
    return nullptr;
  }
  return node->as_table();
}

std::string toml_float(double v) {
  if (std::isinf(v)) return v > 0 ? "inf" : "-inf";
  if (std::isnan(v)) return "nan";
  char buf[64];
  std::snprintf(buf, sizeof buf, "%.9g", v);
  std::string s = buf;
  if (s.find_first_of(".eE") == std::string::npos) s += ".0";
  return s;
}

std::string toml_string(const std::string& s) {
  std::ostringstream out;
  out << toml::value<std::string>(s);
  return out.str();
}

const char* to_string(DivergenceMode mode) {
  return mode == DivergenceMode::Spectral ? "spectral" : "central-difference";
}

}  // namespace

std::optional<std::string> load_config_text(const std::string& text, const std::string& origin,
                                            RunConfig& config) {
  toml::table root;
  try {
    root = toml::parse(text, origin);
  } catch (const toml::parse_error& e) {
    std::ostringstream out;
    out << origin << ":" << e.source().begin.line << ":" << e.source().begin.column << ": "
        << e.description();
    return out.str();
  }
  RunConfig c = config;
  std::string error;
  for (const auto& [key, node] : root) {
    static const std::set<std::string> kTables{"daemon", "http", "source", "limits", "pipeline"};
    if (!kTables.count(std::string(key.str()))) {
      return origin + ": unknown table or key '" + std::string(key.str()) + "' (known: [daemon], "
             "[http], [source], [limits], [pipeline])";
    }
  }

  {
    TableReader r(subtable(root, "daemon", error, origin), "daemon", origin);
    r.string("source", c.source);
    std::string out = c.out.string();
    r.string("out", out);
    c.out = out;
    std::array<double, 3> seed{};
    if (r.triple("seed_mm", seed)) {
      c.seed_mm = std::array<float, 3>{static_cast<float>(seed[0]), static_cast<float>(seed[1]),
                                       static_cast<float>(seed[2])};
    }
    r.number("queue_capacity", c.queue_capacity, 1, 64);
    r.string("log_level", c.log_level);
    r.finish();
    if (error.empty()) error = r.error;
  }
  {
    TableReader r(subtable(root, "http", error, origin), "http", origin);
    r.string("address", c.http_address);
    if (r.raw("address")) c.http_explicit = true;
    r.boolean("allow_remote", c.allow_remote_http);
    r.finish();
    if (error.empty()) error = r.error;
  }
  {
    TableReader r(subtable(root, "source", error, origin), "source", origin);
    r.number("rate_hz", c.rate_hz, 0, 1000);
    std::array<double, 3> dims{};
    if (r.triple("max_dims", dims)) {
      for (int i = 0; i < 3; ++i) {
        if (dims[i] < 1 || dims[i] > 65535 || dims[i] != std::floor(dims[i])) {
          r.fail("max_dims", "must be whole numbers in [1, 65535]");
        }
        c.max_dims[i] = static_cast<int>(dims[i]);
      }
    }
    r.number("max_payload_bytes", c.max_payload_bytes, 1, 1ull << 40);
    r.string("record_path", c.record_path);
    r.number("connect_timeout_ms", c.connect_timeout_ms, 1, 600000);
    r.finish();
    if (error.empty()) error = r.error;
  }
  {
    TableReader r(subtable(root, "limits", error, origin), "limits", origin);
    r.number("max_lost_lines", c.max_lost_lines, 0, 1e12);
    r.number("keep_meshes", c.keep_meshes, 0, 1e12);
    r.finish();
    if (error.empty()) error = r.error;
  }
  {
    const toml::table* pt = subtable(root, "pipeline", error, origin);
    PipelineConfig& p = c.pipeline;
    TableReader r(pt, "pipeline", origin);
    if (const toml::node* sigma = r.raw("smooth_sigma_mm")) {
      if (auto s = sigma->value_exact<std::string>(); s && *s == "auto") {
        p.smooth_sigma_mm.reset();
      } else if (auto v = sigma->value<double>(); v && *v >= 0 && *v <= 20) {
        p.smooth_sigma_mm = static_cast<float>(*v);
      } else {
        r.fail("smooth_sigma_mm", "must be \"auto\" or a number of mm in [0, 20]");
      }
    }
    r.boolean("cell_from_voxel", p.cell_from_voxel);
    r.boolean("reinflate", p.reinflate);
    r.number("reinflate_max_move_vox", p.reinflate_pass.max_move_vox, 1e-3, 20);
    r.number("reinflate_max_iterations", p.reinflate_pass.max_iterations, 1, 10000);
    r.finish({"balloon", "poisson"});
    if (error.empty()) error = r.error;

    const toml::table* bt = pt ? subtable(*pt, "balloon", error, origin) : nullptr;
    TableReader b(bt, "pipeline.balloon", origin);
    segment::BalloonOptions& o = p.balloon;
    b.number("time_step", o.time_step, 1e-3, 10);
    b.number("inflation_vox", o.inflation_vox, 1e-3, 10);
    b.number("umbrella_weight", o.umbrella_weight, 0, 10);
    b.number("initial_radius_vox", o.initial_radius_vox, 0.5, 100);
    b.boolean("relative_cost", o.relative_cost);
    b.number("tau_cost", o.tau_cost, 0, 1e6);
    b.number("tau_cost_fraction", o.tau_cost_fraction, 0, 1);
    b.number("climb_backstop_fraction", o.climb_backstop_fraction, 0, 1);
    b.number("cost_window_vox", o.cost_window_vox, 0, 1e4);
    b.boolean("rise_per_axis", o.rise_per_axis);
    b.boolean("noise_allowance", o.noise_allowance);
    b.boolean("snap_to_wall", o.snap_to_wall);
    b.number("snap_back_vox", o.snap_back_vox, 0, 8);
    b.number("snap_ahead_vox", o.snap_ahead_vox, 0, 8);
    b.number("snap_min_slope", o.snap_min_slope, 0, 10);
    b.number("tau_curv", o.tau_curv, 0, 2);
    b.number("self_intersection_cos", o.self_intersection_cos, -1, 1);
    b.number("target_edge_vox", o.target_edge_vox, 0.25, 20);
    b.number("remesh_every_iterations", o.remesh_every_iterations, 1, 1000);
    b.number("max_iterations", o.max_iterations, 1, 1000000);
    b.number("max_area_fraction", o.max_area_fraction, 1e-3, 100);
    b.number("stall_window_iterations", o.stall_window_iterations, 1, 100000);
    b.number("stall_motion_vox", o.stall_motion_vox, 0, 10);
    b.number("threads", o.threads, 0, 256);
    b.finish();
    if (error.empty()) error = b.error;

    const toml::table* qt = pt ? subtable(*pt, "poisson", error, origin) : nullptr;
    TableReader q(qt, "pipeline.poisson", origin);
    reconstruct::PoissonOptions& po = p.poisson;
    q.number("cell_mm", po.cell_mm, 1e-3, 100);
    q.number("padding_fraction", po.padding_fraction, 0.1, 2);
    q.number("smoothing_cells", po.smoothing_cells, 0, 20);
    q.number("min_feature_cells", po.min_feature_cells, 0, 16);
    q.number("min_cell_fraction", po.min_cell_fraction, 0.1, 1);
    q.number("max_grid_dim", po.max_grid_dim, 16, 2048);
    q.number("fft_threads", po.fft_threads, 1, 256);
    std::string divergence = to_string(po.divergence);
    q.string("divergence", divergence);
    if (divergence == "spectral") {
      po.divergence = DivergenceMode::Spectral;
    } else if (divergence == "central-difference") {
      po.divergence = DivergenceMode::CentralDifference;
    } else {
      q.fail("divergence", "must be \"spectral\" or \"central-difference\"");
    }
    q.boolean("measure_fft_plans", po.measure_fft_plans);
    q.finish();
    if (error.empty()) error = q.error;
  }
  if (!error.empty()) return error;
  config = c;
  return std::nullopt;
}

std::optional<std::string> load_config_file(const std::filesystem::path& path, RunConfig& config) {
  std::ifstream in(path, std::ios::binary);
  if (!in) return "cannot read config file " + path.string();
  std::ostringstream text;
  text << in.rdbuf();
  return load_config_text(text.str(), path.string(), config);
}

std::string to_toml(const RunConfig& c) {
  std::ostringstream o;
  const PipelineConfig& p = c.pipeline;
  const segment::BalloonOptions& b = p.balloon;
  const reconstruct::PoissonOptions& q = p.poisson;
  o << "# sonomeshd run: effective configuration (defaults < --config file < flags)\n\n"
    << "[daemon]\n"
    << "source = " << toml_string(c.source) << "\n"
    << "out = " << toml_string(c.out.string()) << "\n";
  if (c.seed_mm) {
    o << "seed_mm = [" << toml_float((*c.seed_mm)[0]) << ", " << toml_float((*c.seed_mm)[1])
      << ", " << toml_float((*c.seed_mm)[2]) << "]\n";
  } else {
    o << "# seed_mm = [x, y, z]  # unset: sim: phantom seed, else the volume centre\n";
  }
  o << "queue_capacity = " << c.queue_capacity << "\n"
    << "log_level = " << toml_string(c.log_level) << "\n\n"
    << "[http]\n"
    << "address = " << toml_string(c.http_address) << "  # \"off\" disables\n"
    << "allow_remote = " << (c.allow_remote_http ? "true" : "false") << "\n\n"
    << "[source]\n"
    << "rate_hz = " << toml_float(c.rate_hz) << "\n"
    << "max_dims = [" << c.max_dims[0] << ", " << c.max_dims[1] << ", " << c.max_dims[2] << "]\n"
    << "max_payload_bytes = " << c.max_payload_bytes << "\n"
    << "record_path = " << toml_string(c.record_path) << "\n"
    << "connect_timeout_ms = " << c.connect_timeout_ms << "\n\n"
    << "[limits]\n"
    << "max_lost_lines = " << c.max_lost_lines << "\n"
    << "keep_meshes = " << c.keep_meshes << "  # 0 keeps all\n\n"
    << "[pipeline]\n"
    << "smooth_sigma_mm = "
    << (p.smooth_sigma_mm ? toml_float(*p.smooth_sigma_mm) : std::string("\"auto\"")) << "\n"
    << "reinflate = " << (p.reinflate ? "true" : "false")
    << "  # second balloon pass from the reconstruction back to the wall\n"
    << "reinflate_max_move_vox = " << toml_float(p.reinflate_pass.max_move_vox) << "\n"
    << "reinflate_max_iterations = " << p.reinflate_pass.max_iterations << "\n"
    << "cell_from_voxel = " << (p.cell_from_voxel ? "true" : "false")
    << "  # true: poisson.cell_mm = the finest voxel spacing\n\n"
    << "[pipeline.balloon]\n"
    << "time_step = " << toml_float(b.time_step) << "\n"
    << "inflation_vox = " << toml_float(b.inflation_vox) << "\n"
    << "umbrella_weight = " << toml_float(b.umbrella_weight) << "\n"
    << "initial_radius_vox = " << toml_float(b.initial_radius_vox) << "\n"
    << "relative_cost = " << (b.relative_cost ? "true" : "false") << "\n"
    << "tau_cost = " << toml_float(b.tau_cost) << "\n"
    << "tau_cost_fraction = " << toml_float(b.tau_cost_fraction) << "\n"
    << "climb_backstop_fraction = " << toml_float(b.climb_backstop_fraction) << "\n"
    << "cost_window_vox = " << toml_float(b.cost_window_vox) << "  # 0: the paper's plain sum\n"
    << "rise_per_axis = " << (b.rise_per_axis ? "true" : "false") << "  # false: the paper's dot product\n"
    << "noise_allowance = " << (b.noise_allowance ? "true" : "false") << "\n"
    << "snap_to_wall = " << (b.snap_to_wall ? "true" : "false")
    << "  # a stopped vertex ends on the slope's peak along its normal\n"
    << "snap_back_vox = " << toml_float(b.snap_back_vox) << "\n"
    << "snap_ahead_vox = " << toml_float(b.snap_ahead_vox) << "\n"
    << "snap_min_slope = " << toml_float(b.snap_min_slope) << "  # least <grad I, n> / I per voxel\n"
    << "tau_curv = " << toml_float(b.tau_curv) << "\n"
    << "self_intersection_cos = " << toml_float(b.self_intersection_cos) << "\n"
    << "target_edge_vox = " << toml_float(b.target_edge_vox) << "\n"
    << "remesh_every_iterations = " << b.remesh_every_iterations << "\n"
    << "max_iterations = " << b.max_iterations << "\n"
    << "max_area_fraction = " << toml_float(b.max_area_fraction)
    << "  # leak bound, of the volume's bounding-box area\n"
    << "stall_window_iterations = " << b.stall_window_iterations << "\n"
    << "stall_motion_vox = " << toml_float(b.stall_motion_vox) << "\n"
    << "threads = " << b.threads << "\n\n"
    << "[pipeline.poisson]\n"
    << "cell_mm = " << toml_float(q.cell_mm) << "\n"
    << "padding_fraction = " << toml_float(q.padding_fraction) << "\n"
    << "smoothing_cells = " << toml_float(q.smoothing_cells) << "\n"
    << "min_feature_cells = " << toml_float(q.min_feature_cells)
    << "  # a finer cell where the samples have a thinner gap or solid; 0: off\n"
    << "min_cell_fraction = " << toml_float(q.min_cell_fraction) << "\n"
    << "max_grid_dim = " << q.max_grid_dim << "\n"
    << "fft_threads = " << q.fft_threads << "\n"
    << "divergence = " << toml_string(to_string(q.divergence)) << "\n"
    << "measure_fft_plans = " << (q.measure_fft_plans ? "true" : "false") << "\n";
  return o.str();
}

std::optional<std::string> validate(const RunConfig& c, bool require_io) {
  if (require_io && c.source.empty()) return "no source: give --source or [daemon] source";
  if (require_io && c.out.empty()) return "no output directory: give --out or [daemon] out";
  if (c.queue_capacity < 1) return "queue_capacity must be at least 1";
  static const std::set<std::string> kLevels{"trace", "debug", "info", "warn", "error", "critical",
                                             "off"};
  if (!kLevels.count(c.log_level)) {
    return "log_level must be one of trace, debug, info, warn, error, critical, off";
  }
  if (c.http_address != "off") {
    const auto address = parse_http_address(c.http_address);
    if (!address) return "bad HTTP address '" + c.http_address + "' (want HOST:PORT)";
    if (!is_loopback_host(address->host) && !c.allow_remote_http) {
      return "HTTP address " + c.http_address +
             " is not a loopback address; the status server has no authentication, pass "
             "--allow-remote-http to expose it anyway";
    }
  }
  const auto& b = c.pipeline.balloon;
  if (b.time_step * b.inflation_vox > 0.5f) {
    return "pipeline.balloon: time_step * inflation_vox must be <= 0.5 voxel per iteration";
  }
  if (b.time_step * b.umbrella_weight > 1.0f) {
    return "pipeline.balloon: time_step * umbrella_weight must be <= 1";
  }
  return std::nullopt;
}

acquire::SourceOptions source_options(const RunConfig& c) {
  acquire::SourceOptions o;
  o.max_dims = c.max_dims;
  o.max_payload_bytes = c.max_payload_bytes;
  o.rate_hz = c.rate_hz;
  o.record_path = c.record_path;
  o.connect_timeout = std::chrono::milliseconds(c.connect_timeout_ms);
  return o;
}

}  // namespace sonomesh::daemon
