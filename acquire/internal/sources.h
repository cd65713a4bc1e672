#pragma once
/// @file
/// @brief Factories open_source() dispatches to, one per URI scheme (internal).

#include <map>
#include <memory>
#include <string>

#include <tl/expected.hpp>

#include "acquire/acquire.h"

namespace sonomesh::acquire::internal {

/// "PATH?key=value&key2=value2" -> path and query (no percent-decoding; keys are plain words).
struct SplitSpec {
  std::string path;
  std::map<std::string, std::string> query;
};
SplitSpec split_query(const std::string& spec);

/// The reader registered with set_volume_file_reader (empty if none).
VolumeFileReader volume_file_reader();

/// `spec` is the URI without its scheme, e.g. "/tmp/p.sock" for unix:/tmp/p.sock.
tl::expected<std::unique_ptr<Source>, AcquireError> open_unix_source(const std::string& spec,
                                                                     const SourceOptions& options);
tl::expected<std::unique_ptr<Source>, AcquireError> open_tcp_source(const std::string& spec,
                                                                    const SourceOptions& options);
tl::expected<std::unique_ptr<Source>, AcquireError> open_replay_source(const std::string& spec,
                                                                       const SourceOptions& options);
/// usb:VID:PID[/SERIAL] -> spec "VID:PID[/SERIAL]" (owned by helper "hil": usb_source.cpp).
tl::expected<std::unique_ptr<Source>, AcquireError> open_usb_source(const std::string& spec,
                                                                    const SourceOptions& options);
/// v4l2:/dev/videoN[?slices=N] -> spec "/dev/videoN[?slices=N]" (hil: v4l2_source.cpp).
tl::expected<std::unique_ptr<Source>, AcquireError> open_v4l2_source(const std::string& spec,
                                                                     const SourceOptions& options);

}  // namespace sonomesh::acquire::internal
