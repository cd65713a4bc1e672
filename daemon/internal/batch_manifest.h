#pragma once
/// @file
/// @brief `sonomeshd batch`: the manifest (one JSON object per line: input, a seed, optional id
/// and target) and DIR/results.jsonl, appended under an exclusive flock(2) so that several
/// processes (Slurm array tasks, GNU parallel on a shared file system) can share one out dir.

#include <array>
#include <cstddef>
#include <filesystem>
#include <nlohmann/json.hpp>
#include <optional>
#include <set>
#include <string>
#include <vector>

#include "daemon/pipeline.h"

namespace sonomesh::daemon {

struct BatchItem {
  std::size_t index = 0;  // 0-based among the manifest's entries (blank lines are not entries)
  std::size_t line = 0;   // 1-based line number in the file, for messages
  std::string id;         // "id", else the input's file name without its extensions
  std::filesystem::path input;  // relative paths are relative to the manifest's directory
  std::optional<std::array<float, 3>> seed_mm;
  std::optional<std::array<int, 3>> seed_index;
  std::optional<TargetPolarity> target;
};

/// Reads and checks the whole manifest. On any problem: nothing, and `error` names the line and
/// what is wrong (unparsable JSON, no input, neither or both seeds, a bad id or target, an id
/// that two lines share).
std::optional<std::vector<BatchItem>> read_manifest(const std::filesystem::path& path,
                                                    std::string& error);

/// "dark", "bright", "auto" -> the polarity.
std::optional<TargetPolarity> target_from(const std::string& text);

class ResultsFile {
 public:
  /// @throws std::runtime_error naming the file if it cannot be opened for appending.
  explicit ResultsFile(std::filesystem::path path);
  ~ResultsFile();
  ResultsFile(const ResultsFile&) = delete;
  ResultsFile& operator=(const ResultsFile&) = delete;

  /// Ids that already have a line (processed or failed), read under a shared lock. A torn last
  /// line (a process killed mid-write) is ignored.
  std::set<std::string> done_ids() const;
  /// Appends one line under an exclusive lock, after a newline if a torn line ends the file;
  /// fsync'd. With `unless_done`, first checks (under the same lock) that no line has this id
  /// yet and returns false without writing if one has. @throws std::runtime_error on I/O errors.
  bool append(const nlohmann::json& line, bool unless_done = false);

 private:
  std::filesystem::path path_;
  int fd_ = -1;
};

}  // namespace sonomesh::daemon
