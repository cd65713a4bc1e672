// replay:PATH - a .usv recording (paced) or a directory of volume files (via the registered reader).
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
  return tl::make_unexpected(AcquireError{AcquireError::Code::EndOfStream, 0, std::move(why), {}, 0});
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
      return tl::make_unexpected(AcquireError{AcquireError::Code::NotFound, errno,
                                              path_.string() + ": cannot open", {}, 0});
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
          return tl::make_unexpected(AcquireError{AcquireError::Code::IoError, errno,
                                                  path_.string() + ": read failed", {}, 0});
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
      : PacedSource(std::move(uri), options), files_(std::move(files)), reader_(std::move(reader)) {}

 protected:
  bool has_timestamps() const override { return false; }

  tl::expected<RawVolume, AcquireError> produce() override {
    if (index_ >= files_.size()) return end_error("end of replay (" + std::to_string(files_.size()) +
                                                  " files)");
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
    volume->timestamp_ns =
        options_.rate_hz > 0
            ? static_cast<std::uint64_t>(std::llround(static_cast<double>(sequence) * 1e9 /
                                                      options_.rate_hz))
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
      return tl::make_unexpected(
          AcquireError{AcquireError::Code::BadRecord, 0, std::string("cannot read: ") + e.what(), {}, 0});
    }
  }

  std::vector<fs::path> files_;
  VolumeFileReader reader_;
  std::size_t index_ = 0;
};

bool is_volume_file(const fs::path& p) {
  std::string ext = p.extension().string();
  std::transform(ext.begin(), ext.end(), ext.begin(), [](unsigned char c) { return std::tolower(c); });
  return ext == ".nrrd" || ext == ".nhdr" || ext == ".mha" || ext == ".mhd";
}

}  // namespace

tl::expected<std::unique_ptr<Source>, AcquireError> open_replay_source(const std::string& spec,
                                                                       const SourceOptions& options) {
  const SplitSpec split = split_query(spec);
  SourceOptions opts = options;
  const std::string uri = "replay:" + spec;
  auto invalid = [&](std::string what) {
    return tl::make_unexpected(
        AcquireError{AcquireError::Code::InvalidArgument, 0, uri + ": " + what, {}, 0});
  };
  for (const auto& [key, value] : split.query) {
    if (key != "rate") return invalid("unknown option '" + key + "' (rate=HZ)");
    char* end = nullptr;
    const double rate = std::strtod(value.c_str(), &end);
    if (value.empty() || *end != '\0' || !(rate > 0) || !std::isfinite(rate)) {
      return invalid("rate must be a positive number of Hz");
    }
    opts.rate_hz = rate;
  }
  if (opts.rate_hz < 0 || !std::isfinite(opts.rate_hz)) return invalid("rate_hz must be >= 0");
  const fs::path path = split.path;
  std::error_code ec;
  const auto status = fs::status(path, ec);
  if (ec || !fs::exists(status)) {
    return tl::make_unexpected(
        AcquireError{AcquireError::Code::NotFound, ENOENT, uri + ": no such file or directory", {}, 0});
  }
  if (fs::is_directory(status) || is_volume_file(path)) {
    std::vector<fs::path> files;
    if (fs::is_directory(status)) {
      for (const auto& entry : fs::directory_iterator(path, ec)) {
        if (entry.is_regular_file() && is_volume_file(entry.path())) files.push_back(entry.path());
      }
      std::sort(files.begin(), files.end());
      if (files.empty()) return invalid("no .nrrd/.nhdr/.mha/.mhd files in the directory");
    } else {
      files.push_back(path);
    }
    VolumeFileReader reader = volume_file_reader();
    if (!reader) {
      return invalid("replay of volume files needs a volume file reader "
                     "(set_volume_file_reader; sonomeshd registers one)");
    }
    return std::make_unique<FileListReplaySource>(uri, std::move(files), std::move(reader), opts);
  }
  auto source = std::make_unique<UsvReplaySource>(uri, path, opts);
  if (auto r = source->open(); !r) return tl::make_unexpected(r.error());
  return source;
}

}  // namespace sonomesh::acquire::internal
