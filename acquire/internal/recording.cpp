// tee_to_recording(): appends every good volume to a .usv file (the bytes the probe sent).
#include <cerrno>
#include <cstring>
#include <fstream>

#include "acquire/acquire.h"
#include "acquire/protocol.h"

namespace sonomesh::acquire {
namespace {

class TeeSource final : public Source {
 public:
  TeeSource(std::unique_ptr<Source> inner, std::filesystem::path path, std::ofstream out)
      : inner_(std::move(inner)), path_(std::move(path)), out_(std::move(out)) {}

  tl::expected<RawVolume, AcquireError> next(std::chrono::milliseconds timeout) override {
    if (held_) {
      RawVolume v = std::move(*held_);
      held_.reset();
      return v;
    }
    auto r = inner_->next(timeout);
    if (!recording_) return r;
    if (r) {
      // Records are encoded deterministically, so this is byte for byte what the probe sent.
      auto bytes = encode(*r);
      if (bytes) {
        next_sequence_ = r->sequence + 1;
        if (write(*bytes)) return r;
      }
      // The volume itself is fine; report the recording problem first, then hand it out.
      held_ = std::move(*r);
      recording_ = false;
      return tl::make_unexpected(AcquireError{
          AcquireError::Code::IoError,
          errno,
          "recording to " + path_.string() +
              " stopped: " + (bytes ? std::string(std::strerror(errno)) : bytes.error().detail),
          {},
          0});
    }
    if (r.error().code == AcquireError::Code::EndOfStream && !eos_written_) {
      eos_written_ = true;
      const auto now_ns = std::chrono::duration_cast<std::chrono::nanoseconds>(
          std::chrono::system_clock::now().time_since_epoch());
      write(encode_end_of_stream(next_sequence_, static_cast<std::uint64_t>(now_ns.count())));
    }
    return r;
  }

  std::string describe() const override {
    return inner_->describe() + " (recording to " + path_.string() + ")";
  }
  bool live() const override { return inner_->live(); }
  void interrupt() override { inner_->interrupt(); }

 private:
  // A decoded volume (replay of a file) is recorded from its probe voxels.
  static tl::expected<std::vector<std::uint8_t>, AcquireError> encode(const RawVolume& v) {
    if (!v.voxels.empty() || !v.decoded) return encode_volume_record(v);
    RawVolume copy = v;
    copy.voxels = v.decoded->probe_voxels();
    copy.decoded.reset();
    return encode_volume_record(copy);
  }

  bool write(const std::vector<std::uint8_t>& bytes) {
    out_.write(reinterpret_cast<const char*>(bytes.data()),
               static_cast<std::streamsize>(bytes.size()));
    out_.flush();  // a crash keeps every record written so far
    return static_cast<bool>(out_);
  }

  std::unique_ptr<Source> inner_;
  std::filesystem::path path_;
  std::ofstream out_;
  std::optional<RawVolume> held_;
  std::uint64_t next_sequence_ = 0;
  bool recording_ = true;
  bool eos_written_ = false;
};

}  // namespace

tl::expected<std::unique_ptr<Source>, AcquireError> tee_to_recording(
    std::unique_ptr<Source> inner, const std::filesystem::path& path) {
  if (!inner) {
    return tl::make_unexpected(
        AcquireError{AcquireError::Code::InvalidArgument, 0, "tee_to_recording: no source", {}, 0});
  }
  std::ofstream out(path, std::ios::binary | std::ios::trunc);
  if (!out) {
    return tl::make_unexpected(
        AcquireError{AcquireError::Code::IoError,
                     errno,
                     path.string() + ": cannot create recording: " + std::strerror(errno),
                     {},
                     0});
  }
  return std::make_unique<TeeSource>(std::move(inner), path, std::move(out));
}

}  // namespace sonomesh::acquire
