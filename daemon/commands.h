#pragma once
/// @file
/// @brief The sonomeshd subcommands; each registers itself on the CLI11 app.

#include <CLI/CLI.hpp>

namespace sonomesh::daemon {

/// `sonomeshd process INPUT ...` (daemon/process_command.cpp). Sets exit_code when it runs.
void add_process_command(CLI::App& app, int& exit_code);

/// `sonomeshd run --source SOURCE --out DIR ...` (daemon/run_command.cpp). Sets exit_code.
void add_run_command(CLI::App& app, int& exit_code);

/// `sonomeshd batch --manifest FILE.jsonl --out DIR [--jobs N] [--index I]`
/// (daemon/batch_command.cpp). Sets exit_code.
void add_batch_command(CLI::App& app, int& exit_code);

}  // namespace sonomesh::daemon
