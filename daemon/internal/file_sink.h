#pragma once
/// @file
/// @brief The files under OUT: meshes/SEQ.ply, reports/SEQ.json and latest.ply, each written
/// whole or not at all (outputs.h), the oldest pruned beyond `keep_meshes`.

#include <cstdint>
#include <deque>
#include <filesystem>
#include <optional>
#include <string>
#include <utility>

#include "daemon/internal/output_sink.h"
#include "daemon/internal/run_config.h"

namespace sonomesh::daemon {

class FileSink : public OutputSink {
 public:
  FileSink(std::filesystem::path out, const SharedConfig& config)
      : out_(std::move(out)), config_(config) {}
  const char* name() const override { return "files"; }
  /// Adds "mesh", "report" (paths relative to OUT) and "latency_ms" (until the mesh was in place).
  void write(const ProcessedVolume& volume, nlohmann::json& line) override;

 private:
  void prune(std::uint64_t keep);

  std::filesystem::path out_;
  const SharedConfig& config_;
  std::deque<std::string> written_stems_;  // oldest first; writer thread only
  // (epoch, sequence) of the volume latest.ply holds: a lane's older volume may finish after it.
  std::optional<std::pair<std::uint64_t, std::uint64_t>> latest_;
};

}  // namespace sonomesh::daemon
