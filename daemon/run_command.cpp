// `sonomeshd run`: the daemon. Configuration, signals and HTTP here; the threads in LiveRunner.
#include <pthread.h>
#include <signal.h>
#include <spdlog/sinks/stdout_color_sinks.h>
#include <spdlog/spdlog.h>

#include <atomic>
#include <chrono>
#include <cstdio>
#include <iostream>
#include <memory>
#include <optional>
#include <thread>

#include "daemon/commands.h"
#include "daemon/huge_pages.h"
#include "daemon/internal/http_status.h"
#include "daemon/internal/igtl_server.h"
#include "daemon/internal/live_extras.h"
#include "daemon/internal/live_runner.h"
#include "daemon/internal/run_config.h"
#include "daemon/internal/run_options.h"
#include "daemon/internal/run_sources.h"

namespace sonomesh::daemon {

namespace {

struct RunFlags {
  std::string source;
  std::string out;
  std::string config_file;
  std::string seed_text;
  std::string http;
  bool allow_remote_http = false;
  bool print_config = false;
  std::size_t queue_capacity = 0;
  std::string log_level;
  double rate_hz = 0;
  std::string record;
  std::uint64_t keep_meshes = 0;
  std::string target;
  std::string igtl_listen;
  bool igtl_any_address = false;
  // Which were given (flags override the file only when given).
  CLI::Option* o_source = nullptr;
  CLI::Option* o_out = nullptr;
  CLI::Option* o_seed = nullptr;
  CLI::Option* o_http = nullptr;
  CLI::Option* o_allow_remote = nullptr;
  CLI::Option* o_queue = nullptr;
  CLI::Option* o_log = nullptr;
  CLI::Option* o_rate = nullptr;
  CLI::Option* o_record = nullptr;
  CLI::Option* o_keep = nullptr;
  CLI::Option* o_target = nullptr;
  CLI::Option* o_igtl = nullptr;
  CLI::Option* o_igtl_any = nullptr;
};

// Defaults, then the file, then the flags. Returns an error line.
std::optional<std::string> effective_config(const RunFlags& f, RunConfig& config) {
  config = RunConfig{};
  if (!f.config_file.empty()) {
    if (auto err = load_config_file(f.config_file, config)) return err;
  }
  if (f.o_source->count()) config.source = f.source;
  if (f.o_out->count()) config.out = f.out;
  if (f.o_seed->count()) {
    const auto seed = parse_seed_text(f.seed_text);
    if (!seed) return "--seed-mm: want X,Y,Z in mm, got '" + f.seed_text + "'";
    config.seed_mm = *seed;
  }
  if (f.o_http->count()) {
    config.http_address = f.http;
    config.http_explicit = true;
  }
  if (f.o_allow_remote->count()) config.allow_remote_http = f.allow_remote_http;
  if (f.o_queue->count()) config.queue_capacity = f.queue_capacity;
  if (f.o_log->count()) config.log_level = f.log_level;
  if (f.o_rate->count()) config.rate_hz = f.rate_hz;
  if (f.o_record->count()) config.record_path = f.record;
  if (f.o_keep->count()) config.keep_meshes = f.keep_meshes;
  if (f.o_target->count()) {
    const OptionSpec* spec = find_option("pipeline", "target");
    if (auto err = check_value(*spec, OptionValue(f.target))) return "--target " + *err;
    spec->set(config, OptionValue(f.target));
  }
  if (f.o_igtl->count()) config.igtl_listen = f.igtl_listen;
  if (f.o_igtl_any->count()) config.igtl_any_address = f.igtl_any_address;
  // The labels go out as OpenIGTLink IMAGE sonomesh-labels only (seed tracking takes the deepest
  // point from χ): without a listener they are not made.
  config.pipeline.want_labels = !config.igtl_listen.empty();
  // --print-config also serves to start a configuration file: no source or output needed.
  return validate(config, !f.print_config);
}

void setup_logging(const std::string& level) {
  auto logger = spdlog::stderr_color_mt("sonomeshd");
  logger->set_pattern("%Y-%m-%d %H:%M:%S.%e %^%l%$ %v");
  spdlog::set_default_logger(logger);
  spdlog::set_level(spdlog::level::from_str(level));
  spdlog::flush_on(spdlog::level::info);
}

// The signal thread: SIGINT/SIGTERM stop the runner, SIGHUP reloads the configuration file.
void take_signals(const sigset_t& signals, const RunFlags& flags, LiveRunner& runner,
                  LiveExtras& extras, const std::atomic<bool>& done) {
  // A stop signal that follows the previous one within this window is the same request:
  // `timeout` and a terminal both deliver SIGINT to the child and again to its process group,
  // and that must finish the volume in hand, not abort it.
  constexpr auto kSameRequestWindow = std::chrono::milliseconds(500);
  std::optional<std::chrono::steady_clock::time_point> last_stop_signal;
  while (!done) {
    timespec timeout{0, 200 * 1000 * 1000};
    const int sig = sigtimedwait(&signals, nullptr, &timeout);
    if (sig == SIGINT || sig == SIGTERM) {
      const auto now = std::chrono::steady_clock::now();
      if (last_stop_signal && now - *last_stop_signal < kSameRequestWindow) continue;
      last_stop_signal = now;
      spdlog::info("{}: stopping after the volume in hand (again to abort it)",
                   sig == SIGINT ? "SIGINT" : "SIGTERM");
      runner.event("signal", {{"signal", sig == SIGINT ? "SIGINT" : "SIGTERM"}});
      extras.stop_requested();  // web: STOPPING=1
      runner.request_stop();
    } else if (sig == SIGHUP) {
      if (flags.config_file.empty()) {
        spdlog::info("SIGHUP: no --config file to reload");
        continue;
      }
      RunConfig next;
      if (auto err = effective_config(flags, next)) {
        spdlog::error("SIGHUP: keeping the running configuration: {}", *err);
        runner.event("config_reload_failed", {{"error", *err}});
      } else {
        runner.reload(next);
      }
    }
  }
}

// The OpenIGTLink server, added to the runner's sinks; null (after one line on stderr) if it
// cannot listen.
std::shared_ptr<IgtlServer> start_igtl(const RunConfig& config, LiveRunner& runner) {
  auto igtl = std::make_shared<IgtlServer>(runner.stats());
  try {
    const HttpAddress address = *parse_http_address(config.igtl_listen);
    const int port = igtl->start(address);
    spdlog::info("OpenIGTLink server on {}:{} (sonomesh-mesh, -labels, -status)", address.host,
                 port);
    runner.event("igtl_listening", {{"host", address.host}, {"port", port}});
  } catch (const std::exception& e) {
    std::fprintf(stderr, "sonomeshd run: %s\n", e.what());
    return nullptr;
  }
  runner.add_sink(igtl);
  return igtl;
}

// Signals are taken synchronously by one thread (sigtimedwait): they are blocked before any
// thread starts so that every thread inherits the mask and none is interrupted in the middle of
// I/O.
sigset_t block_signals() {
  sigset_t signals;
  sigemptyset(&signals);
  sigaddset(&signals, SIGINT);
  sigaddset(&signals, SIGTERM);
  sigaddset(&signals, SIGHUP);
  pthread_sigmask(SIG_BLOCK, &signals, nullptr);
  ::signal(SIGPIPE, SIG_IGN);  // a client closing its socket is not a reason to die
  return signals;
}

// The source opened and the runner built on it; null (the reason printed) when either fails.
std::unique_ptr<LiveRunner> make_runner(const RunConfig& config, bool& live) {
  OpenedSource opened = open_run_source(config);
  if (opened.fatal_error) {
    std::fprintf(stderr, "sonomeshd run: %s\n", opened.fatal_error->c_str());
    return nullptr;
  }
  live = opened.live;
  try {
    return std::make_unique<LiveRunner>(config, std::move(opened.source), std::move(opened.factory),
                                        opened.live, opened.phantom_seed_mm);
  } catch (const std::exception& e) {
    std::fprintf(stderr, "sonomeshd run: %s\n", e.what());
    return nullptr;
  }
}

// The HTTP status server, unless "off". An address that cannot be bound is fatal (false) when
// it was asked for, else the daemon runs without it.
bool start_http(const RunConfig& config, LiveRunner& runner, LiveExtras& extras,
                std::unique_ptr<HttpStatusServer>& http) {
  if (config.http_address == "off") return true;
  const HttpAddress address = *parse_http_address(config.http_address);
  http = std::make_unique<HttpStatusServer>(
      runner.stats(), config.out / "latest.ply",
      [&runner](const std::array<float, 3>& seed) { return runner.set_seed(seed); });
  http->set_web(extras.web());
  try {
    const int port = http->start(address);
    spdlog::info("HTTP status on http://{}:{}/status, live page http://{}:{}/", address.host, port,
                 address.host, port);
    runner.event("http_listening", {{"host", address.host}, {"port", port}});
  } catch (const std::exception& e) {
    http.reset();
    if (config.http_explicit) {
      std::fprintf(stderr, "sonomeshd run: %s\n", e.what());
      return false;
    }
    spdlog::warn("{}; running without the HTTP status server", e.what());
  }
  return true;
}

int run_daemon(const RunFlags& flags) {
  RunConfig config;
  if (auto err = effective_config(flags, config)) {
    std::fprintf(stderr, "sonomeshd run: %s\n", err->c_str());
    return 2;
  }
  if (flags.print_config) {
    std::cout << to_toml(config);
    return 0;
  }
  if (!spdlog::get("sonomeshd")) setup_logging(config.log_level);
  if (const double ms = keep_heap_warm(config.heap_reserve_mb); ms > 0.0)
    spdlog::debug("heap: {} MB touched in {:.0f} ms", config.heap_reserve_mb, ms);
  const sigset_t signals = block_signals();
  bool live = false;
  const std::unique_ptr<LiveRunner> runner = make_runner(config, live);
  if (!runner) return 1;
  std::shared_ptr<IgtlServer> igtl;
  if (!config.igtl_listen.empty()) {
    igtl = start_igtl(config, *runner);
    if (!igtl) return 1;
  }
  // web (issue 18): the live page's event stream and slices, systemd's notify protocol.
  LiveExtras extras(config.out, runner->stats());
  runner->set_worker_turn_hook(extras.worker_turn_hook());
  runner->add_sink(extras.slice_sink());
  extras.start();
  std::unique_ptr<HttpStatusServer> http;
  if (!start_http(config, *runner, extras, http)) return 1;

  extras.serving(true);  // web: READY=1 once the source is open too
  spdlog::info("sonomeshd run: source {} ({}), out {}", config.source,
               live ? "live: newest volume wins" : "replay: every volume", config.out.string());
  std::atomic<bool> done{false};
  std::thread signal_thread([&] { take_signals(signals, flags, *runner, extras, done); });
  const int rc = runner->run();
  done = true;
  signal_thread.join();
  extras.stop();  // web: ends the event streams first, or the HTTP server would wait for them
  if (http) http->stop();
  spdlog::info("journal: {}", (config.out / "journal.jsonl").string());
  return rc;
}

}  // namespace

void add_run_command(CLI::App& app, int& exit_code) {
  auto flags = std::make_shared<RunFlags>();
  CLI::App* cmd = app.add_subcommand(
      "run", "Run as a daemon: volumes from a probe source -> meshes, journal, HTTP status");
  flags->o_source = cmd->add_option("--source", flags->source,
                                    "sim:PHANTOM[?rate=HZ&size=N], replay:PATH, unix:PATH, "
                                    "tcp:HOST:PORT, usb:VID:PID[/SERIAL], v4l2:/dev/videoN");
  flags->o_out =
      cmd->add_option("--out", flags->out, "Output directory (journal, meshes, reports)");
  cmd->add_option("--config", flags->config_file, "TOML configuration file (SIGHUP reloads it)")
      ->check(CLI::ExistingFile);
  flags->o_seed = cmd->add_option("--seed-mm", flags->seed_text,
                                  "Seed X,Y,Z in mm (else the phantom's / the volume centre)");
  flags->o_http = cmd->add_option(
      "--http", flags->http,
      std::string("HTTP status address HOST:PORT or 'off' (default ") + kDefaultHttpAddress + ")");
  flags->o_allow_remote = cmd->add_flag("--allow-remote-http", flags->allow_remote_http,
                                        "Allow a non-loopback HTTP address");
  cmd->add_flag("--print-config", flags->print_config,
                "Print the effective configuration as TOML and exit");
  flags->o_queue = cmd->add_option("--queue-capacity", flags->queue_capacity,
                                   "Volumes waiting for the worker (default 2)");
  flags->o_log = cmd->add_option("--log-level", flags->log_level,
                                 "trace, debug, info, warn, error (default info)");
  flags->o_rate =
      cmd->add_option("--rate", flags->rate_hz, "Replay pacing in volumes/s (0: recorded timing)");
  flags->o_record =
      cmd->add_option("--record", flags->record, "Also record every good volume to this .usv file");
  flags->o_keep = cmd->add_option("--keep-meshes", flags->keep_meshes,
                                  "Keep only the newest N meshes and reports (0: all)");
  flags->o_target = cmd->add_option("--target", flags->target,
                                    "dark, bright or auto: the target's polarity (default dark)");
  flags->o_igtl = cmd->add_option("--igtl-listen", flags->igtl_listen,
                                  "OpenIGTLink server ADDR:PORT for 3D Slicer (loopback)");
  flags->o_igtl_any = cmd->add_flag("--igtl-any-address", flags->igtl_any_address,
                                    "Allow a non-loopback --igtl-listen address");
  cmd->callback([flags, &exit_code] {
    try {
      exit_code = run_daemon(*flags);
    } catch (const std::exception& e) {
      std::fprintf(stderr, "sonomeshd run: %s\n", e.what());
      exit_code = 1;
    }
  });
}

}  // namespace sonomesh::daemon
