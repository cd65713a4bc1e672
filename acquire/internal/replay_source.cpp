// replay:PATH - a .usv recording (paced) or volume files (through the application's reader).
#include <algorithm>
#include <cerrno>
#include <cmath>
#include <cstring>
#include <fstream>
#include <vector>

#include "acquire/internal/sources.h"
#include "acquire/internal/stream_decoder.h"
#include "acquire/internal/waker.h"

namespace sonomesh::acquire::internal {
namespace {

using Clock = std::chrono::steady_clock;
namespace fs = std::filesystem;

tl::unexpected<AcquireError> timeout_error() {
  return tl::make_unexpected(AcquireError{AcquireError::Code::Timeout, 0, "no volume due", {}, 0});
}
tl::unexpected<AcquireError> end_error(std::string why) {
  return tl::make_unexpected(
      AcquireError{AcquireError::Code::EndOfStream, 0, std::move(why), {}, 0});
}

// Shared pacing: a volume is handed out at its due time; next() waits for it up to its timeout.
class PacedSource : public Source {
 public:
  PacedSource(std::string uri, const SourceOptions& options)
      : uri_(std::move(uri)), options_(options) {}

  tl::expected<RawVolume, AcquireError> next(std::chrono::milliseconds timeout) override {
    const auto deadline = Clock::now() + timeout;
    if (!pending_) {
      auto r = produce();
      if (!r) return tl::make_unexpected(r.error());
      pending_ = std::move(*r);
      pending_due_ = due_time(*pending_);
    }
    if (pending_due_ > deadline) {
      waker_.sleep_until(deadline);
      return timeout_error();
    }
    if (waker_.sleep_until(pending_due_)) return timeout_error();
    RawVolume v = std::move(*pending_);
    pending_.reset();
    v.received = Clock::now();
    ++delivered_;
    return v;
  }

  std::string describe() const override { return uri_; }
  bool live() const override { return !options_.replay_blocking; }
  void interrupt() override { waker_.wake(); }

 protected:
  /// The next volume in file order (or an error to return as is).
  virtual tl::expected<RawVolume, AcquireError> produce() = 0;
  /// True if the recorded timestamps pace the replay when rate_hz is 0.
  virtual bool has_timestamps() const = 0;

  std::string uri_;
  SourceOptions options_;

 private:
  Clock::time_point due_time(const RawVolume& v) {
    const auto now = Clock::now();
    if (delivered_ == 0) {
      start_ = now;
      first_ts_ns_ = v.timestamp_ns;
      return now;
    }
    if (options_.rate_hz > 0) {
      return start_ + std::chrono::nanoseconds(static_cast<std::int64_t>(
                          std::llround(static_cast<double>(delivered_) * 1e9 / options_.rate_hz)));
    }
    if (!has_timestamps() || v.timestamp_ns < first_ts_ns_) return now;
    return start_ + std::chrono::nanoseconds(v.timestamp_ns - first_ts_ns_);
  }

  Waker waker_;
  std::optional<RawVolume> pending_;
  Clock::time_point pending_due_{};
  Clock::time_point start_{};
  std::uint64_t first_ts_ns_ = 0;
  std::uint64_t delivered_ = 0;
};

class UsvReplaySource final : public PacedSource {
 public:
  UsvReplaySource(std::string uri, fs::path path, const SourceOptions& options)
      : PacedSource(std::move(uri), options), path_(std::move(path)), decoder_(options) {}

  tl::expected<void, AcquireError> open() {
    file_.open(path_, std::ios::binary);
    if (!file_) {
      return tl::make_unexpected(AcquireError{
          AcquireError::Code::NotFound, errno, path_.string() + ": cannot open", {}, 0});
    }
    return {};
  }

 protected:
  bool has_timestamps() const override { return true; }

  tl::expected<RawVolume, AcquireError> produce() override {
    for (;;) {
      if (finished_) return end_error("end of recording");
      if (auto r = decoder_.next()) {
        if (!*r && r->error().code == AcquireError::Code::EndOfStream) finished_ = true;
        return std::move(*r);
      }
      if (at_eof_) {
        finished_ = true;
        return end_error("end of recording " + path_.string());
      }
      std::vector<std::uint8_t> chunk(1 << 20);
      file_.read(reinterpret_cast<char*>(chunk.data()), static_cast<std::streamsize>(chunk.size()));
      const auto got = static_cast<std::size_t>(file_.gcount());
      if (got > 0) decoder_.feed(chunk.data(), got);
      if (got < chunk.size()) {
        if (file_.bad()) {
          finished_ = true;
          return tl::make_unexpected(AcquireError{
              AcquireError::Code::IoError, errno, path_.string() + ": read failed", {}, 0});
        }
        at_eof_ = true;
        decoder_.end_of_input();
      }
    }
  }

 private:
  fs::path path_;
  std::ifstream file_;
  StreamDecoder decoder_;
  bool at_eof_ = false;
  bool finished_ = false;
};

class FileListReplaySource final : public PacedSource {
 public:
  FileListReplaySource(std::string uri, std::vector<fs::path> files, VolumeFileReader reader,
                       const SourceOptions& options)
      : PacedSource(std::move(uri), options),
        files_(std::move(files)),
        reader_(std::move(reader)) {}

 protected:
  bool has_timestamps() const override { return false; }

  tl::expected<RawVolume, AcquireError> produce() override {
    if (index_ >= files_.size()) {
      return end_error("end of replay (" + std::to_string(files_.size()) + " files)");
    }
    const std::uint64_t sequence = index_;
    const fs::path& file = files_[index_++];
    auto volume = read(file);
    if (!volume) {
      AcquireError e = volume.error();
      e.code = AcquireError::Code::BadRecord;
      e.sequence = sequence;
      e.detail = file.filename().string() + ": " + e.detail;
      return tl::make_unexpected(std::move(e));
    }
    for (int a = 0; a < 3; ++a) {
      if (volume->dims[a] > options_.max_dims[a]) {
        return tl::make_unexpected(AcquireError{AcquireError::Code::BadRecord, 0,
                                                file.filename().string() + ": dims above the limit",
                                                sequence, 0});
      }
    }
    volume->sequence = sequence;
    volume->timestamp_ns = options_.rate_hz > 0
                               ? static_cast<std::uint64_t>(std::llround(
                                     static_cast<double>(sequence) * 1e9 / options_.rate_hz))
                               : 0;
    return volume;
  }

 private:
  // A bad file is one rejected record, never the end of the run: whatever the reader throws
  // (an allocation refused, a library's exception) becomes its error.
  tl::expected<RawVolume, AcquireError> read(const fs::path& file) {
    try {
      return reader_(file);
    } catch (const std::exception& e) {
      return tl::make_unexpected(AcquireError{
          AcquireError::Code::BadRecord, 0, std::string("cannot read: ") + e.what(), {}, 0});
    }
  }

  std::vector<fs::path> files_;
  VolumeFileReader reader_;
  std::size_t index_ = 0;
};

// Extensions compare in lower case and whole: "a.nii.gz" has ".gz" and ".nii.gz".
bool is_volume_file(const fs::path& p, const VolumeFiles& files) {
  std::string name = p.filename().string();
  std::transform(name.begin(), name.end(), name.begin(),
                 [](unsigned char c) { return static_cast<char>(std::tolower(c)); });
  return std::any_of(files.extensions.begin(), files.extensions.end(), [&](const std::string& e) {
    return name.size() > e.size() && name.compare(name.size() - e.size(), e.size(), e) == 0;
  });
}

std::string extension_list(const VolumeFiles& files) {
  std::string list;
  for (const auto& e : files.extensions) list += (list.empty() ? "" : "/") + e;
  return list.empty() ? std::string("none registered") : list;
}

tl::expected<std::unique_ptr<Source>, AcquireError> open_replay(const SourceUri& uri,
                                                                const SourceOptions& options,
                                                                const VolumeFiles& files) {
  SourceOptions opts = options;
  auto invalid = [&](std::string what) {
    return tl::make_unexpected(
        AcquireError{AcquireError::Code::InvalidArgument, 0, uri.text + ": " + what, {}, 0});
  };
  if (auto refused = refuse_unknown_keys(uri, {"rate"})) return tl::make_unexpected(*refused);
  if (const auto it = uri.query.find("rate"); it != uri.query.end()) {
    const std::string& value = it->second;
    char* end = nullptr;
    const double rate = std::strtod(value.c_str(), &end);
    if (value.empty() || *end != '\0' || !(rate > 0) || !std::isfinite(rate)) {
      return invalid("rate must be a positive number of Hz");
    }
    opts.rate_hz = rate;
  }
  if (opts.rate_hz < 0 || !std::isfinite(opts.rate_hz)) return invalid("rate_hz must be >= 0");
  const fs::path path = uri.body;
  std::error_code ec;
  const auto status = fs::status(path, ec);
  if (ec || !fs::exists(status)) {
    return tl::make_unexpected(AcquireError{
        AcquireError::Code::NotFound, ENOENT, uri.text + ": no such file or directory", {}, 0});
  }
  if (fs::is_directory(status) || is_volume_file(path, files)) {
    std::vector<fs::path> list;
    if (fs::is_directory(status)) {
      for (const auto& entry : fs::directory_iterator(path, ec)) {
        if (entry.is_regular_file() && is_volume_file(entry.path(), files)) {
          list.push_back(entry.path());
        }
      }
      std::sort(list.begin(), list.end());
      if (list.empty()) return invalid("no volume files (" + extension_list(files) + ") in it");
    } else {
      list.push_back(path);
    }
    if (!files.read) return invalid("replay of volume files needs a volume file reader");
    return std::make_unique<FileListReplaySource>(uri.text, std::move(list), files.read, opts);
  }
  auto source = std::make_unique<UsvReplaySource>(uri.text, path, opts);
  if (auto r = source->open(); !r) return tl::make_unexpected(r.error());
  return source;
}

}  // namespace
}  // namespace sonomesh::acquire::internal

namespace sonomesh::acquire {

SourceOpener replay_opener(VolumeFiles files) {
  return [files = std::move(files)](const SourceUri& uri, const SourceOptions& options) {
    return internal::open_replay(uri, options, files);
  };
}

}  // namespace sonomesh::acquire
