#pragma once
/// @file
/// @brief Non-blocking, interruptible stream-socket connect shared by the socket sources
/// (internal).

#include <chrono>
#include <optional>
#include <string>
#include <tl/expected.hpp>

#include "acquire/acquire.h"
#include "acquire/internal/backoff.h"
#include "acquire/internal/waker.h"

namespace sonomesh::acquire::internal {

struct Endpoint {
  bool is_unix = true;
  std::string path;  // unix
  std::string host;  // tcp
  std::string port;  // tcp
  std::string uri;   // for messages
};

/// "HOST:PORT" (HOST may be "[::1]") -> a tcp Endpoint; nullopt if either part is empty.
std::optional<Endpoint> tcp_endpoint(const std::string& host_port, const std::string& uri);

/// Connects a non-blocking, close-on-exec stream socket to `endpoint`, waiting until `deadline`
/// or a wake of `waker`. NotFound if nobody listens, Timeout if the wait ended first.
tl::expected<int, AcquireError> connect_stream(const Endpoint& endpoint,
                                               std::chrono::steady_clock::time_point deadline,
                                               Waker& waker);

}  // namespace sonomesh::acquire::internal
