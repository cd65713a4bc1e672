#pragma once
/// @file
/// @brief OUT/journal.jsonl (one line per sequence) and OUT/events.jsonl (outages, reloads...).
///
/// Every line is written with a single write(2) on an O_APPEND descriptor and fsync'd before the
/// call returns, so a crash loses at most the line being written and never leaves half of an
/// earlier one. Opening an existing file checks it: a torn last line (power loss mid-write) or any
/// line that is not a JSON object is moved to "<file>.torn" and the file keeps its whole lines, so
/// that a restart on the same out dir appends to a file of whole JSON lines.

#include <cstdint>
#include <filesystem>
#include <functional>
#include <map>
#include <mutex>
#include <nlohmann/json.hpp>
#include <optional>
#include <set>
#include <string>
#include <utility>
#include <vector>

namespace sonomesh::daemon {

/// Wall-clock time now as ISO 8601 UTC with milliseconds, e.g. "2024-05-01T12:00:00.123Z".
std::string utc_timestamp();

/// What opening an existing JSON-lines file found.
struct JsonlRepair {
  std::uint64_t whole_lines = 0;         // lines kept (each a JSON object)
  std::uint64_t set_aside = 0;           // torn or unparsable lines moved out of the file
  std::filesystem::path set_aside_path;  // "<file>.torn" when set_aside > 0
};

/// Checks an existing JSON-lines file and repairs it in place: lines that are not whole JSON
/// objects are appended to "<file>.torn" and the file is rewritten atomically without them (a
/// last line that parses but lacks its newline gets one). `on_line` sees every kept line, in
/// order. A missing file is not an error. @throws std::runtime_error if the file cannot be read
/// or rewritten.
JsonlRepair repair_jsonl(const std::filesystem::path& path,
                         const std::function<void(const nlohmann::json&)>& on_line = {});

/// An append-only JSON-lines file. Thread-safe.
class JsonlFile {
 public:
  /// Repairs (repair_jsonl, with a warning in the log if anything was set aside) and opens
  /// (creates) the file for appending. @throws std::runtime_error naming the file.
  explicit JsonlFile(const std::filesystem::path& path,
                     const std::function<void(const nlohmann::json&)>& on_line = {});
  ~JsonlFile();
  JsonlFile(const JsonlFile&) = delete;
  JsonlFile& operator=(const JsonlFile&) = delete;

  /// Appends one object as one line (adds "time" if absent), flushed and fsync'd.
  /// @throws std::runtime_error if the write fails (disk full...).
  void append(nlohmann::json line);
  const std::filesystem::path& path() const { return path_; }
  /// What the check at opening found.
  const JsonlRepair& repair() const { return repair_; }

 private:
  std::filesystem::path path_;
  JsonlRepair repair_;
  std::mutex mutex_;
  int fd_ = -1;
};

/// Statuses a journal line can have (DESIGN.md "Daemon behaviour").
enum class JournalStatus { Processed, Skipped, Failed, Rejected, Lost };
const char* to_string(JournalStatus status);

/// The journal: exactly one line per sequence number received or inferred.
///
/// A sequence is *claimed* when the acquisition thread takes it over (a volume received, a record
/// rejected, a gap reported) and *written* when its line goes out. A claim that arrives for a
/// sequence already claimed is refused (returns false): e.g. a gap reported by the source for a
/// record the daemon already journaled as rejected does not get a second line. A volume whose
/// sequence repeats one already seen starts a new *epoch* (the probe restarted its counter);
/// lines of later epochs carry "epoch": N so that (epoch, sequence) stays unique.
///
/// A journal opened on an existing file (a restart on the same out dir, e.g. after SIGKILL or
/// power loss) goes on from it: it continues in the epoch of the file's last line with that
/// epoch's sequences already claimed, so no sequence gets a second line.
class Journal {
 public:
  /// @throws std::runtime_error if the file cannot be opened.
  explicit Journal(const std::filesystem::path& path);

  /// What the earlier run left: lines kept and set aside (see JsonlRepair).
  const JsonlRepair& repair() const { return file_.repair(); }
  /// True if `sequence` has a line of the current epoch written by an earlier run.
  bool written_before(std::uint64_t sequence) const;
  /// Highest sequence of the current epoch written by an earlier run (nothing if none).
  std::optional<std::uint64_t> highest_before() const;
  /// Sequences between the earlier run's lowest and highest of the current epoch that have no
  /// line, as (first, count): what that run had in hand when it was killed.
  std::vector<std::pair<std::uint64_t, std::uint64_t>> holes_before() const;

  /// Claims a sequence; false if it already has (or will get) a line in this epoch.
  bool claim(std::uint64_t sequence);
  /// Starts a new epoch (forgets every claim). Returns the new epoch number.
  std::uint64_t new_epoch();
  std::uint64_t epoch() const;

  /// Writes the line of a claimed sequence (or of a rejected record without a sequence:
  /// pass nullopt). `fields` may add anything; sequence, status, epoch and time are set here.
  void write(std::optional<std::uint64_t> sequence, JournalStatus status, nlohmann::json fields,
             std::optional<std::uint64_t> epoch = std::nullopt);

  /// Claims and writes `lost` lines for [first, first + count) that are not yet claimed.
  /// Returns how many lines were written.
  std::uint64_t write_lost(std::uint64_t first, std::uint64_t count, const std::string& reason);

  /// Lines written so far per status (for tests and the final log line).
  std::uint64_t lines_written() const;
  const std::filesystem::path& path() const { return file_.path(); }

 private:
  bool claim_locked(std::uint64_t sequence);

  // What the earlier run's lines say (filled while file_ is opened, so declared before it):
  // the last epoch and its sequences as inclusive ranges first -> last.
  struct Earlier {
    std::uint64_t epoch = 0;
    std::map<std::uint64_t, std::uint64_t> ranges;
    void add(const nlohmann::json& line);
  };
  Earlier earlier_;
  JsonlFile file_;
  mutable std::mutex mutex_;
  std::uint64_t epoch_ = 0;
  // Claimed sequences above `floor_`; everything below `floor_` counts as claimed. Pruned so that
  // a daemon running for weeks keeps a bounded set.
  std::set<std::uint64_t> claimed_;
  std::uint64_t floor_ = 0;
  std::uint64_t lines_ = 0;
};

}  // namespace sonomesh::daemon
