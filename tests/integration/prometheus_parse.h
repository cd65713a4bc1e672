#pragma once
// A strict-enough parser of the Prometheus text exposition format (0.0.4) for the tests: every
// line is a comment, a HELP/TYPE line or a sample; every sample belongs to a family whose TYPE was
// declared before it; values are numbers (or +Inf/-Inf/NaN).

#include <map>
#include <optional>
#include <regex>
#include <sstream>
#include <string>
#include <vector>

namespace sonomesh::testing {

struct PromSample {
  std::string name;
  std::map<std::string, std::string> labels;
  double value = 0;
};

struct PromParse {
  std::vector<PromSample> samples;
  std::map<std::string, std::string> types;  // family -> counter/gauge/summary/histogram/untyped
  std::string error;                         // empty when valid

  std::optional<double> value(const std::string& name,
                              const std::map<std::string, std::string>& labels = {}) const {
    for (const auto& s : samples) {
      if (s.name == name && s.labels == labels) return s.value;
    }
    return std::nullopt;
  }
};

inline PromParse parse_prometheus(const std::string& text) {
  PromParse out;
  static const std::regex kType(
      R"re(^# TYPE ([a-zA-Z_:][a-zA-Z0-9_:]*) (counter|gauge|summary|histogram|untyped)$)re");
  static const std::regex kHelp(R"re(^# HELP ([a-zA-Z_:][a-zA-Z0-9_:]*) .*$)re");
  static const std::regex kSample(
      R"re(^([a-zA-Z_:][a-zA-Z0-9_:]*)(\{([^}]*)\})? ([-+]?(?:[0-9]*\.?[0-9]+(?:[eE][-+]?[0-9]+)?|Inf|NaN))( -?[0-9]+)?$)re");
  static const std::regex kLabel(R"re(^([a-zA-Z_][a-zA-Z0-9_]*)="((?:[^"\\]|\\.)*)"$)re");
  if (text.empty() || text.back() != '\n') {
    out.error = "text does not end with a newline";
    return out;
  }
  std::istringstream in(text);
  std::string line;
  int n = 0;
  while (std::getline(in, line)) {
    ++n;
    std::smatch m;
    if (line.empty()) continue;
    if (std::regex_match(line, m, kType)) {
      if (out.types.count(m[1])) {
        out.error = "line " + std::to_string(n) + ": TYPE declared twice";
        return out;
      }
      out.types[m[1]] = m[2];
      continue;
    }
    if (std::regex_match(line, m, kHelp)) continue;
    if (line[0] == '#') {
      if (line.rfind("# TYPE", 0) == 0 || line.rfind("# HELP", 0) == 0) {
        out.error = "line " + std::to_string(n) + ": malformed " + line;
        return out;
      }
      continue;
    }
    if (!std::regex_match(line, m, kSample)) {
      out.error = "line " + std::to_string(n) + ": not a sample: " + line;
      return out;
    }
    PromSample s;
    s.name = m[1];
    const std::string labels = m[3];
    if (!labels.empty()) {
      std::string part;
      std::istringstream ls(labels);
      while (std::getline(ls, part, ',')) {
        std::smatch lm;
        if (!std::regex_match(part, lm, kLabel)) {
          out.error = "line " + std::to_string(n) + ": bad label " + part;
          return out;
        }
        s.labels[lm[1]] = lm[2];
      }
    }
    const std::string v = m[4];
    s.value = v == "+Inf" || v == "Inf" ? 1e308 * 10 : v == "-Inf" ? -1e308 * 10 : std::stod(v);
    // The family this sample belongs to must have been declared.
    std::string family = s.name;
    for (const char* suffix : {"_bucket", "_sum", "_count"}) {
      const std::string suf = suffix;
      if (!out.types.count(family) && family.size() > suf.size() &&
          family.compare(family.size() - suf.size(), suf.size(), suf) == 0) {
        const std::string base = family.substr(0, family.size() - suf.size());
        if (out.types.count(base)) family = base;
      }
    }
    if (!out.types.count(family)) {
      out.error = "line " + std::to_string(n) + ": sample of undeclared family " + s.name;
      return out;
    }
    const std::string& type = out.types[family];
    if (type == "histogram" && s.name == family + "_bucket" && !s.labels.count("le")) {
      out.error = "line " + std::to_string(n) + ": histogram bucket without le";
      return out;
    }
    out.samples.push_back(std::move(s));
  }
  return out;
}

}  // namespace sonomesh::testing
