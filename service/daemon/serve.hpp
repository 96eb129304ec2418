// `proden serve`: the long-running daemon (HTTP API, watcher, worker pool). Registered on the CLI
// with add_serve_command(); the subcommand's callback runs the daemon and exits the process.
#pragma once

#include <CLI/CLI.hpp>

namespace proden::daemon {

struct Config;

void add_serve_command(CLI::App& app);

// Runs the daemon until SIGTERM/SIGINT; returns a process exit code.
int run_serve(Config config, const std::string& token);

}  // namespace proden::daemon
