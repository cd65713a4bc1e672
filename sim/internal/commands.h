#pragma once
/// @file
/// @brief probe-sim subcommands: each registers itself on the app and reports its exit status.
///
/// Adding a subcommand = one internal/<name>_command.cpp defining add_<name>_command, its
/// declaration here, and one call in probe_sim.cpp.

namespace CLI {
class App;
}

namespace sonomesh::sim::internal {

/// `probe-sim generate`: one phantom volume, its truth labels and a sidecar JSON.
/// The subcommand's callback sets exit_code (0 on success) and prints one line on stderr on error.
void add_generate_command(CLI::App& app, int& exit_code);

/// `probe-sim serve`: phantom volumes or a .usv replay over a socket, with fault injection, or as
/// an OpenIGTLink server (--igtl, internal/igtl_serve.h)
/// (sim/internal/serve.cpp, owned by helper "acquire").
void add_serve_command(CLI::App& app, int& exit_code);

}  // namespace sonomesh::sim::internal
