#pragma once
/// @file
/// @brief The openers acquire registers in its scheme table, one per URI scheme (internal).

#include <memory>
#include <string>
#include <tl/expected.hpp>

#include "acquire/acquire.h"

namespace sonomesh::acquire::internal {

using OpenResult = tl::expected<std::unique_ptr<Source>, AcquireError>;

/// unix:PATH
OpenResult open_unix_source(const SourceUri& uri, const SourceOptions& options);
/// tcp:HOST:PORT
OpenResult open_tcp_source(const SourceUri& uri, const SourceOptions& options);
/// usb:VID:PID[/SERIAL]
OpenResult open_usb_source(const SourceUri& uri, const SourceOptions& options);
/// v4l2:/dev/videoN[?slices=N&format=grey|y16]
OpenResult open_v4l2_source(const SourceUri& uri, const SourceOptions& options);
/// igtl:HOST:PORT[?device=NAME]
OpenResult open_igtl_source(const SourceUri& uri, const SourceOptions& options);

}  // namespace sonomesh::acquire::internal
