// sonomeshd: the per-volume pipeline as a one-shot command (`process`) and as a daemon (`run`).
#include <cstdio>
#include <exception>

#include "daemon/commands.h"
#include "daemon/huge_pages.h"

int main(int argc, char** argv) {
  sonomesh::daemon::tune_heap();
  CLI::App app{"sonomeshd: topologically correct surfaces from 3D ultrasound volumes"};
  app.require_subcommand(1);
  int exit_code = 0;
  sonomesh::daemon::add_process_command(app, exit_code);
  sonomesh::daemon::add_run_command(app, exit_code);
  sonomesh::daemon::add_batch_command(app, exit_code);
  try {
    app.parse(argc, argv);
  } catch (const CLI::CallForHelp& e) {
    return app.exit(e);
  } catch (const CLI::CallForAllHelp& e) {
    return app.exit(e);
  } catch (const CLI::CallForVersion& e) {
    return app.exit(e);
  } catch (const CLI::ParseError& e) {
    // One line naming the problem (CLI11's default adds a usage dump); exit 2 = bad arguments.
    std::fprintf(stderr, "sonomeshd: %s (see sonomeshd --help)\n", e.what());
    return 2;
  } catch (const std::exception& e) {
    // Last line of defence: a bad input must give one line and a non-zero exit, never a crash.
    std::fprintf(stderr, "sonomeshd: %s\n", e.what());
    return 1;
  }
  return exit_code;
}
