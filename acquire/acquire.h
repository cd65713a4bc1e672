#pragma once
/// @file
/// @brief Probe sources: where volumes come from (socket, recording, USB, V4L2), as RawVolume.
///
/// Every source returns errors as values and never throws. The byte format shared by sockets,
/// USB bulk IN and .usv recordings is the probe stream protocol v1 (acquire/protocol.h,
/// docs/protocol.md).

#include <array>
#include <chrono>
#include <cstdint>
#include <filesystem>
#include <functional>
#include <map>
#include <memory>
#include <optional>
#include <string>
#include <tl/expected.hpp>
#include <vector>

#include "acquire/raw_volume.h"

namespace sonomesh::acquire {

struct AcquireError {
  enum class Code {
    Timeout,       // nothing arrived within the timeout (also: next() was interrupted)
    Disconnected,  // the link dropped; the source reconnects with backoff
    BadRecord,     // a record was dropped (corrupt, refused); sequence set if its header was intact
    Lost,          // sequence gap: `count` volumes from `sequence` on never arrived
    Incomplete,    // a record was cut short (link dropped / file ended mid-record)
    EndOfStream,   // clean end: end-of-stream record or end of a recording
    InvalidArgument,  // bad URI / option
    NotFound,         // file, socket or device does not exist / nobody listening
    IoError           // anything else the OS reported
  };
  Code code = Code::IoError;
  int os_errno = 0;                       // errno / translated libusb code where relevant
  std::string detail;                     // one line
  std::optional<std::uint64_t> sequence;  // BadRecord: seq if the header was intact; Lost: first
                                          // missing seq; Incomplete: the volume's seq if known
  std::uint64_t count = 0;                // Lost: how many sequences are missing
};

const char* to_string(AcquireError::Code code);
/// One line: "<code>: <detail> (seq N, count M, errno E)" with the parts that are set.
std::string to_string(const AcquireError& error);

struct SourceOptions {
  std::array<int, 3> max_dims{1024, 1024, 1024};  // refuse larger volumes before allocating
  std::uint64_t max_payload_bytes = 1ull << 30;
  double rate_hz = 0;           // replay pacing: 0 = recorded timestamps (.usv) / unpaced (dir);
                                // >0 = fixed rate
  bool replay_blocking = true;  // true: replay is not live (live() false, daemon processes all)
  int v4l2_slices = 0;          // untagged V4L2: frames per volume (0 = tagged mode)
  std::string record_path;      // non-empty: tee every good volume to this .usv file
  std::chrono::milliseconds connect_timeout{1000};  // socket connect, per attempt
};

class Source {
 public:
  virtual ~Source() = default;
  /// Next volume, or an error value. Never throws. Timeout if nothing within `timeout`.
  /// Gaps: when a volume arrives after a sequence gap, next() first returns Lost{sequence=first
  /// missing, count}, and the volume itself on the following call.
  /// Disconnected: returned once when the link drops; later calls try to reconnect with
  /// backoff (50 ms doubling to 500 ms max, so a returning probe is picked up within a second),
  /// returning Timeout while down and volumes again once it is back.
  /// EndOfStream: the stream ended cleanly (end-of-stream record, end of a recording); every
  /// later call returns EndOfStream again.
  virtual tl::expected<RawVolume, AcquireError> next(std::chrono::milliseconds timeout) = 0;
  virtual std::string describe() const = 0;  // e.g. "unix:/tmp/p.sock"
  virtual bool live() const = 0;             // live: daemon keeps newest; false: replay (may block)
  /// Wakes a blocked next() from another thread (it returns Timeout promptly). Thread-safe.
  /// If no next() is blocked, the following next() returns Timeout at once (the wake is sticky).
  virtual void interrupt() = 0;
};

/// A source URI split once, for every scheme: "SCHEME:BODY[?KEY=VALUE&KEY=VALUE]".
/// No percent-decoding: keys and values are plain words, paths and host names.
struct SourceUri {
  std::string text;    // the whole URI as given
  std::string scheme;  // before the first ':'
  std::string body;    // between the scheme's ':' and the first '?'
  std::map<std::string, std::string> query;
};

/// Splits `uri`. InvalidArgument (naming the URI) without a scheme, or with a query key that is
/// empty or given twice.
tl::expected<SourceUri, AcquireError> parse_source_uri(const std::string& uri);

/// InvalidArgument naming the first query key of `uri` that is not in `allowed`, if any.
std::optional<AcquireError> refuse_unknown_keys(const SourceUri& uri,
                                                const std::vector<std::string>& allowed);

using SourceOpener = std::function<tl::expected<std::unique_ptr<Source>, AcquireError>(
    const SourceUri& uri, const SourceOptions& options)>;

/// One entry of the scheme table open_source() dispatches through.
struct SourceScheme {
  std::string name;     // "tcp"
  std::string usage;    // "tcp:HOST:PORT", for error messages and --help
  bool device = false;  // a probe or server that may come up later: a caller may wait for it
  SourceOpener open;
};

/// Adds a scheme or replaces the one of the same name (the application adds those acquire
/// cannot build itself: sonomeshd adds sim: and replay with its volume file reader).
/// Thread-safe.
void register_source_scheme(SourceScheme scheme);
/// The registered scheme of that name, if any. Thread-safe.
std::optional<SourceScheme> find_source_scheme(const std::string& name);
/// Every registered scheme's usage line, sorted by name.
std::vector<std::string> source_scheme_usages();

/// Opens a source through the scheme table. acquire registers:
///   unix:PATH, tcp:HOST:PORT          probe stream over a socket (connects now; fails if nobody
///                                     listens; reconnects with backoff after a drop)
///   replay:FILE.usv[?rate=HZ]         a recorded probe stream, paced (not live)
///   replay:DIR[?rate=HZ]              volume files sorted by name, sequence = index (needs the
///   replay:FILE.nrrd (...)            reader an application registers: replay_opener())
///   usb:VID:PID[/SERIAL]              USB bulk probe (hex VID/PID)
///   v4l2:/dev/videoN[?slices=N&format=grey|y16]  frame grabber probe
///   igtl:HOST:PORT[?device=NAME]      IMAGE messages from an OpenIGTLink server (PlusServer)
/// With options.record_path set, the source is wrapped by tee_to_recording().
tl::expected<std::unique_ptr<Source>, AcquireError> open_source(const std::string& uri,
                                                                const SourceOptions& options = {});

/// Wraps a source so that every good volume it returns is appended to a .usv recording (the
/// exact record bytes the probe sent: records are encoded deterministically), and end of stream
/// writes an end-of-stream record. replay: reads the file back.
tl::expected<std::unique_ptr<Source>, AcquireError> tee_to_recording(
    std::unique_ptr<Source> inner, const std::filesystem::path& path);

/// Reads one volume file into a RawVolume; a reader that decodes into its own type hands it over
/// in RawVolume::decoded instead of voxel bytes (no byte round trip).
using VolumeFileReader =
    std::function<tl::expected<RawVolume, AcquireError>(const std::filesystem::path&)>;

/// The volume files replay can read: acquire does not depend on volume/ (dependencies point one
/// way), so the application supplies the reader and the extensions it reads.
struct VolumeFiles {
  std::vector<std::string> extensions;  // lower case, with the dot: ".nrrd", ".nii.gz"
  VolumeFileReader read;
};

/// The replay: opener: .usv recordings always; directories and single files with one of
/// `files.extensions` through `files.read`. acquire registers replay_opener({}).
SourceOpener replay_opener(VolumeFiles files);

}  // namespace sonomesh::acquire
