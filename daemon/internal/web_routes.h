#pragma once
/// @file
/// @brief The live page's routes on the daemon's HTTP server: GET / (the page), /static/* (its
/// scripts and styles), /three/* (Debian's libjs-three), /slices/{axial,coronal,sagittal}.png,
/// /slices/info and /events (Server-Sent Events). Everything is served from local files: an
/// operating-room network has no internet.

#include <filesystem>

namespace httplib {
class Server;
}

namespace sonomesh::daemon {

class EventHub;
class SliceRenderer;

struct WebContext {
  EventHub* events = nullptr;       // null: no /events
  SliceRenderer* slices = nullptr;  // null: no /slices
  std::filesystem::path web_dir;    // index.html, app.js, style.css
  std::filesystem::path three_dir;  // three.min.js, examples/js/...
};

/// The page's files: $SONOMESH_WEB_DIR, else share/sonomesh/web next to the installed binary,
/// else the source tree's daemon/web (a build run in place).
std::filesystem::path locate_web_dir();
/// three.js: $SONOMESH_THREE_DIR, else where the build found libjs-three
/// (/usr/share/javascript/three).
std::filesystem::path locate_three_dir();

/// Registers the routes. The server's worker pool is enlarged so that open event streams (at
/// most EventHub::kMaxStreams) leave threads for the other requests.
void add_web_routes(httplib::Server& server, const WebContext& context);

}  // namespace sonomesh::daemon
