#include "daemon/internal/web_routes.h"

#include <unistd.h>

#include <cstdlib>
#include <fstream>
#include <memory>
#include <nlohmann/json.hpp>
#include <sstream>

// clang-format off
// Before httplib.h: it pulls in <resolv.h>, whose `_res` macro breaks Eigen's parameter names.
#include "daemon/internal/event_hub.h"
#include "daemon/internal/slice_renderer.h"
#include <httplib.h>
// clang-format on

#ifndef SONOMESH_SOURCE_WEB_DIR
#define SONOMESH_SOURCE_WEB_DIR ""
#endif
#ifndef SONOMESH_THREE_JS_DIR
#define SONOMESH_THREE_JS_DIR "/usr/share/javascript/three"
#endif

namespace sonomesh::daemon {

namespace fs = std::filesystem;

namespace {

// A stream waits this long for a journal line before it sends a state event or a keep-alive.
constexpr auto kStreamWait = std::chrono::milliseconds(1000);
// Worker threads: the streams plus room for the page's other requests and /metrics scrapes.
constexpr std::size_t kHttpThreads = EventHub::kMaxStreams + 8;

fs::path executable_dir() {
  std::error_code ec;
  const fs::path exe = fs::read_symlink("/proc/self/exe", ec);
  return ec ? fs::path() : exe.parent_path();
}

void json_error(httplib::Response& res, int status, const std::string& message) {
  res.status = status;
  res.set_content(nlohmann::json{{"error", message}}.dump() + "\n", "application/json");
}

void add_event_route(httplib::Server& server, EventHub& hub) {
  server.Get("/events", [&hub](const httplib::Request& req, httplib::Response& res) {
    if (!hub.try_open_stream()) {
      json_error(res, 503, "too many event streams open");
      return;
    }
    // Browsers send the last id they saw in the header; the query form (?last_event_id=) is for
    // clients that cannot set headers.
    std::string last_id = req.get_header_value("Last-Event-ID");
    if (last_id.empty() && req.has_param("last_event_id")) {
      last_id = req.get_param_value("last_event_id");
    }
    auto stream = std::make_shared<EventStream>(hub, last_id);
    res.set_header("Cache-Control", "no-store");
    res.set_header("X-Accel-Buffering", "no");
    res.set_chunked_content_provider(
        "text/event-stream",
        [stream](std::size_t, httplib::DataSink& sink) {
          const std::optional<std::string> chunk = stream->next(kStreamWait);
          if (!chunk) {
            sink.done();  // the daemon is stopping: end the stream cleanly
            return true;
          }
          return sink.write(chunk->data(), chunk->size());  // false: the client went away
        },
        [&hub](bool) { hub.close_stream(); });
  });
}

void add_slice_routes(httplib::Server& server, SliceRenderer& slices) {
  server.Get(R"(/slices/(\w+)\.png)",
             [&slices](const httplib::Request& req, httplib::Response& res) {
               const auto axis = slice_axis_from(req.matches[1]);
               if (!axis) return json_error(res, 404, "slices are axial, coronal and sagittal");
               const auto png = slices.png(*axis);
               if (!png) return json_error(res, 404, "no result yet");
               if (png->empty()) return json_error(res, 500, "PNG encoding failed");
               res.set_header("Cache-Control", "no-store");
               res.set_content(*png, "image/png");
             });
  server.Get("/slices/info", [&slices](const httplib::Request&, httplib::Response& res) {
    res.set_header("Cache-Control", "no-store");
    res.set_content(slices.info().dump() + "\n", "application/json");
  });
}

}  // namespace

fs::path locate_web_dir() {
  if (const char* env = std::getenv("SONOMESH_WEB_DIR"); env && *env) return env;
  std::error_code ec;
  const fs::path installed = executable_dir() / ".." / "share" / "sonomesh" / "web";
  if (fs::is_regular_file(installed / "index.html", ec)) return fs::weakly_canonical(installed, ec);
  return SONOMESH_SOURCE_WEB_DIR;
}

fs::path locate_three_dir() {
  if (const char* env = std::getenv("SONOMESH_THREE_DIR"); env && *env) return env;
  return SONOMESH_THREE_JS_DIR;
}

void add_web_routes(httplib::Server& server, const WebContext& context) {
  server.new_task_queue = [] { return new httplib::ThreadPool(kHttpThreads); };
  server.set_file_extension_and_mimetype_mapping("js", "text/javascript");
  server.set_file_extension_and_mimetype_mapping("css", "text/css");
  server.set_file_extension_and_mimetype_mapping("html", "text/html; charset=utf-8");
  std::error_code ec;
  const bool have_page = fs::is_regular_file(context.web_dir / "index.html", ec);
  if (have_page) server.set_mount_point("/static", context.web_dir.string());
  if (fs::is_directory(context.three_dir, ec)) {
    server.set_mount_point("/three", context.three_dir.string());
  }
  const fs::path index = context.web_dir / "index.html";
  server.Get("/", [index, have_page](const httplib::Request&, httplib::Response& res) {
    std::ifstream in(index, std::ios::binary);
    if (!have_page || !in) {
      return json_error(
          res, 404,
          "the live page is not installed (" + index.string() + "; set SONOMESH_WEB_DIR)");
    }
    std::ostringstream bytes;
    bytes << in.rdbuf();
    res.set_content(bytes.str(), "text/html; charset=utf-8");
  });
  if (context.events) add_event_route(server, *context.events);
  if (context.slices) add_slice_routes(server, *context.slices);
}

}  // namespace sonomesh::daemon
