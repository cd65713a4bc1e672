/// probe-sim: what a probe would deliver, without a probe. See DESIGN.md "Command-line contract".
#include <CLI/CLI.hpp>
#include <iostream>

#include "sim/internal/commands.h"

int main(int argc, char** argv) {
  CLI::App app{"probe-sim: synthetic 3D ultrasound phantoms with ground truth"};
  app.require_subcommand(1);
  int exit_code = 0;
  sonomesh::sim::internal::add_generate_command(app, exit_code);
  sonomesh::sim::internal::add_serve_command(app, exit_code);
  try {
    app.parse(argc, argv);
  } catch (const CLI::CallForHelp& e) {
    return app.exit(e);
  } catch (const CLI::CallForAllHelp& e) {
    return app.exit(e);
  } catch (const CLI::ParseError& e) {
    // One line, naming the problem; CLI11's own exit() would add a second line.
    std::cerr << "probe-sim: " << e.what() << '\n';
    return e.get_exit_code() != 0 ? e.get_exit_code() : 2;
  }
  return exit_code;
}
