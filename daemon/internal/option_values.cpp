// What an option's value may be, and how it is written (run_options.h): ranges, the checks of a
// value against its spec and of the options against each other, the TOML text.
#include <toml++/toml.h>

#include <charconv>
#include <cmath>
#include <sstream>

#include "daemon/internal/run_config.h"
#include "daemon/internal/run_options.h"

namespace sonomesh::daemon {
namespace {

using K = OptionKind;

std::string number_text(double v) {
  std::ostringstream out;
  out << v;
  return out.str();
}

}  // namespace

bool OptionRange::contains(double v) const {
  if (!std::isfinite(v)) return false;
  return (lo_open ? v > lo : v >= lo) && (hi_open ? v < hi : v <= hi);
}

std::string OptionRange::text() const {
  return std::string(lo_open ? "(" : "[") + number_text(lo) + ", " + number_text(hi) +
         (hi_open ? ")" : "]");
}

std::optional<std::string> check_value(const OptionSpec& spec, const OptionValue& value) {
  const std::string unit = *spec.unit ? std::string(" ") + spec.unit : std::string();
  auto in_range = [&](double v) -> std::optional<std::string> {
    if (!spec.range.contains(v)) {
      return "must be in " + spec.range.text() + unit + ", got " + number_text(v);
    }
    return std::nullopt;
  };
  switch (spec.kind) {
    case K::Integer:
      if (auto err = in_range(std::get<double>(value))) return err;
      if (std::get<double>(value) != std::floor(std::get<double>(value)))
        return std::string("must be a whole number");
      return std::nullopt;
    case K::Number:
      return in_range(std::get<double>(value));
    case K::NumberOrAuto:
      if (std::holds_alternative<std::string>(value)) {
        if (std::get<std::string>(value) == "auto") return std::nullopt;
        return std::string("must be \"auto\" or a number");
      }
      return in_range(std::get<double>(value));
    case K::Triple:
      if (std::holds_alternative<std::monostate>(value)) return std::nullopt;
      for (double v : std::get<std::array<double, 3>>(value)) {
        if (auto err = in_range(v)) return err;
        if (spec.range.lo >= 1 && v != std::floor(v)) return std::string("must be whole numbers");
      }
      return std::nullopt;
    case K::Choice: {
      const std::string& s = std::get<std::string>(value);
      std::string list;
      for (const std::string& c : spec.choices) {
        if (c == s) return std::nullopt;
        list += (list.empty() ? "\"" : ", \"") + c + "\"";
      }
      return "must be one of " + list + ", got \"" + s + "\"";
    }
    case K::Bool:
    case K::String:
      return std::nullopt;
  }
  return std::nullopt;
}

std::optional<std::string> check_cross_rules(const RunConfig& c) {
  // The balloon's own check, so a configuration that loads is one the balloon runs with.
  if (const std::string problem = segment::validate(c.pipeline.balloon); !problem.empty())
    return "pipeline.balloon: " + problem;
  return std::nullopt;
}

std::string option_toml(const OptionValue& value) {
  struct Print {
    std::string operator()(std::monostate) const { return ""; }
    std::string operator()(bool b) const { return b ? "true" : "false"; }
    std::string operator()(double v) const {
      if (v == std::floor(v) && std::fabs(v) < 1e15) {
        return std::to_string(static_cast<long long>(v));
      }
      // The shortest text that reads back as the same value: a float field's as a float (0.45,
      // not 0.449999988), any other as a double.
      char buf[64];
      const auto f = static_cast<float>(v);
      const char* end = static_cast<double>(f) == v ? std::to_chars(buf, buf + sizeof buf, f).ptr
                                                    : std::to_chars(buf, buf + sizeof buf, v).ptr;
      std::string s(buf, static_cast<std::size_t>(end - buf));
      if (s.find_first_of(".eEn") == std::string::npos) s += ".0";
      return s;
    }
    std::string operator()(const std::string& s) const {
      std::ostringstream out;
      out << toml::value<std::string>(s);
      return out.str();
    }
    std::string operator()(const std::array<double, 3>& a) const {
      return "[" + (*this)(a[0]) + ", " + (*this)(a[1]) + ", " + (*this)(a[2]) + "]";
    }
  };
  return std::visit(Print{}, value);
}

}  // namespace sonomesh::daemon
