#include "daemon/internal/run_config.h"

#include <toml++/toml.h>

#include <cmath>
#include <fstream>
#include <set>
#include <sstream>

#include "daemon/internal/http_status.h"
#include "daemon/internal/run_options.h"

namespace sonomesh::daemon {

namespace {

std::set<std::string> known_tables() {
  std::set<std::string> tables;
  for (const OptionSpec& spec : run_options()) {
    const std::string t = spec.table;
    tables.insert(t);
    if (const auto dot = t.find('.'); dot != std::string::npos) tables.insert(t.substr(0, dot));
  }
  return tables;
}

std::optional<double> toml_number(const toml::node& node) {
  if (auto i = node.value_exact<std::int64_t>()) return static_cast<double>(*i);
  if (auto f = node.value_exact<double>()) return *f;
  return std::nullopt;
}

// The TOML node as the option's kind of value, or the complaint about its type.
std::variant<OptionValue, std::string> read_node(const OptionSpec& spec, const toml::node& node) {
  switch (spec.kind) {
    case OptionKind::Bool:
      if (auto b = node.value_exact<bool>()) return OptionValue(*b);
      return std::string("must be true or false");
    case OptionKind::Number:
    case OptionKind::Integer:
      if (auto v = toml_number(node)) return OptionValue(*v);
      return std::string("must be a number");
    case OptionKind::String:
    case OptionKind::Choice:
      if (auto s = node.value_exact<std::string>()) return OptionValue(*s);
      return std::string("must be a string");
    case OptionKind::NumberOrAuto:
      if (auto s = node.value_exact<std::string>()) return OptionValue(*s);
      if (auto v = toml_number(node)) return OptionValue(*v);
      return std::string("must be \"auto\" or a number");
    case OptionKind::Triple: {
      const toml::array* arr = node.as_array();
      std::array<double, 3> out{};
      if (!arr || arr->size() != 3) return std::string("must be an array of three numbers");
      for (std::size_t i = 0; i < 3; ++i) {
        const auto v = toml_number(*arr->get(i));
        if (!v) return std::string("must be an array of three numbers");
        out[i] = *v;
      }
      return OptionValue(out);
    }
  }
  return std::string("has an unknown kind");
}

// Reads every key of `table` (named `prefix`) into `config`; the first problem ends it.
std::optional<std::string> read_table(const toml::table& table, const std::string& prefix,
                                      const std::string& origin,
                                      const std::set<std::string>& tables, RunConfig& config) {
  for (const auto& [key_view, node] : table) {
    const std::string key(key_view.str());
    const std::string name = prefix.empty() ? key : prefix + "." + key;
    if (tables.count(name)) {
      if (!node.is_table()) return origin + ": [" + name + "] must be a table";
      if (auto err = read_table(*node.as_table(), name, origin, tables, config)) return err;
      continue;
    }
    if (prefix.empty()) {
      return origin + ": unknown table or key '" + key +
             "' (known: [daemon], [http], [source], [limits], [outputs], [pipeline])";
    }
    const OptionSpec* spec = find_option(prefix, key);
    // A typo in a key must not be silently ignored in a clinical setting.
    if (!spec) return origin + ": " + name + " is not a known option";
    auto value = read_node(*spec, node);
    if (auto* complaint = std::get_if<std::string>(&value)) {
      return origin + ": " + name + " " + *complaint;
    }
    const OptionValue& v = std::get<OptionValue>(value);
    if (auto err = check_value(*spec, v)) return origin + ": " + name + " " + *err;
    spec->set(config, v);
  }
  return std::nullopt;
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
  if (auto err = read_table(root, "", origin, known_tables(), c)) return err;
  // What loads must run: the rules between options are checked here too, not first per volume.
  if (auto err = check_cross_rules(c)) return origin + ": " + *err;
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
  o << "# sonomeshd run: effective configuration (defaults < --config file < flags)\n";
  std::string table;
  for (const OptionSpec& spec : run_options()) {
    if (spec.table != table) {
      table = spec.table;
      o << "\n[" << table << "]\n";
    }
    const OptionValue value = spec.get(c);
    std::string note = spec.doc;
    if (spec.kind == OptionKind::Number || spec.kind == OptionKind::Integer ||
        spec.kind == OptionKind::NumberOrAuto || spec.kind == OptionKind::Triple) {
      note += " " + spec.range.text() + (*spec.unit ? std::string(" ") + spec.unit : "");
    }
    if (std::holds_alternative<std::monostate>(value)) {
      o << "# " << spec.key << " = ...  # " << note << "\n";
    } else {
      o << spec.key << " = " << option_toml(value) << "  # " << note << "\n";
    }
  }
  return o.str();
}

namespace {
std::optional<std::string> check_listen_address(const std::string& what, const std::string& text,
                                                bool allowed, const char* flag) {
  const auto address = parse_http_address(text);
  if (!address) return "bad " + what + " address '" + text + "' (want HOST:PORT)";
  if (!is_loopback_host(address->host) && !allowed) {
    return what + " address " + text +
           " is not a loopback address; the server has no "
           "authentication, pass " +
           flag + " to expose it anyway";
  }
  return std::nullopt;
}
}  // namespace

std::optional<std::string> validate(const RunConfig& c, bool require_io) {
  if (require_io && c.source.empty()) return "no source: give --source or [daemon] source";
  if (require_io && c.out.empty()) return "no output directory: give --out or [daemon] out";
  // The same checks as the loader's, for values that came from flags.
  for (const OptionSpec& spec : run_options()) {
    if (auto err = check_value(spec, spec.get(c))) return spec.name() + " " + *err;
  }
  if (auto err = check_cross_rules(c)) return err;
  if (c.http_address != "off") {
    if (auto err = check_listen_address("HTTP", c.http_address, c.allow_remote_http,
                                        "--allow-remote-http")) {
      return err;
    }
  }
  if (!c.igtl_listen.empty()) {
    if (auto err = check_listen_address("OpenIGTLink", c.igtl_listen, c.igtl_any_address,
                                        "--igtl-any-address")) {
      return err;
    }
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
