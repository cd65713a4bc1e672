#pragma once
/// @file
/// @brief Non-blocking, interruptible stream-socket connect shared by the socket sources
/// (internal).

#include <chrono>
#include <cstddef>
#include <cstdint>
#include <functional>
#include <optional>
#include <string>
#include <tl/expected.hpp>
#include <vector>

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

/// One reconnect step of a socket source: a connect attempt when `backoff` is due (until
/// `deadline`, at most `connect_timeout`), else a wait for the next attempt. The connected
/// descriptor; -1: try again; nullopt: the deadline passed or the waker woke (a Timeout).
std::optional<int> reconnect_step(const Endpoint& endpoint, Backoff& backoff, Waker& waker,
                                  std::chrono::steady_clock::time_point deadline,
                                  std::chrono::milliseconds connect_timeout);

enum class SocketWait { Readable, Timeout, Failed };

/// Waits for input on `fd` until `deadline` or a wake of the waker (then drained): Timeout.
/// Failed leaves errno as poll set it.
SocketWait wait_readable(int fd, Waker& waker, std::chrono::steady_clock::time_point deadline);

/// Why receive_available found the link down: `why` for the message, `err` the errno (0: closed).
struct LinkDown {
  std::string why;
  int err = 0;
};

/// Reads what `fd` has now into `feed`, `buffer` at a time, at most 16 buffers (so that a fast
/// sender cannot starve the caller); stops at a short read, when it would block, or when `feed`
/// returns false. nullopt while the link is up; an orderly close reads "closed by the <peer>".
std::optional<LinkDown> receive_available(
    int fd, std::vector<std::uint8_t>& buffer, const char* peer,
    const std::function<bool(const std::uint8_t*, std::size_t)>& feed);

}  // namespace sonomesh::acquire::internal
