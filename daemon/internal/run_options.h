#pragma once
/// @file
/// @brief Every option of `sonomeshd run`, declared once: TOML table and key, unit, range and a
/// one-line doc. The table drives the TOML loader, `--print-config` and validation, so a value
/// the loader accepts is a value the pipeline runs with.

#include <array>
#include <functional>
#include <optional>
#include <string>
#include <variant>
#include <vector>

namespace sonomesh::daemon {

struct RunConfig;

/// An option's value as TOML sees it: nothing (unset), a boolean, a number, a string, or three
/// numbers.
using OptionValue = std::variant<std::monostate, bool, double, std::string, std::array<double, 3>>;

enum class OptionKind { Bool, Number, Integer, String, Choice, Triple, NumberOrAuto };

struct OptionRange {
  double lo = 0, hi = 0;
  bool lo_open = false, hi_open = false;  // (lo, ...] or [..., hi)
  bool contains(double v) const;
  std::string text() const;  // "[1, 100]", "(0, 1)"
};

struct OptionSpec {
  const char* table;  // "daemon", "pipeline.balloon", ...
  const char* key;
  OptionKind kind;
  const char* unit;                  // "mm", "vox", "ms", "" for none
  OptionRange range;                 // numbers and each element of a triple
  std::vector<std::string> choices;  // Choice: the allowed strings
  const char* doc;
  std::function<OptionValue(const RunConfig&)> get;
  std::function<void(RunConfig&, const OptionValue&)> set;

  std::string name() const { return std::string(table) + "." + key; }
};

/// The table, in the order --print-config prints it.
const std::vector<OptionSpec>& run_options();
/// The option named "table.key", or null.
const OptionSpec* find_option(const std::string& table, const std::string& key);

/// Why `value` is not acceptable for `spec` ("must be in [1, 100] vox, got 0.5"), or nullopt.
std::optional<std::string> check_value(const OptionSpec& spec, const OptionValue& value);

/// The rules between options (steps that could jump a wall, a snap window over 8 voxels).
std::optional<std::string> check_cross_rules(const RunConfig& config);

/// `value` as TOML text.
std::string option_toml(const OptionValue& value);

}  // namespace sonomesh::daemon
