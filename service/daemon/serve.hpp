// `proden serve`: the long-running daemon (HTTP API, watcher, worker pool). Registered on the CLI
// with add_serve_command(); the subcommand's callback runs the daemon and exits the process.
#pragma once

#include <CLI/CLI.hpp>
#include <string>

namespace proden::daemon {

struct Config;

// `large_blocks`: how the executable allocates large blocks (huge_pages_name() where it links
// service/huge_pages.cpp), for the start-up log line; empty = not said.
void add_serve_command(CLI::App& app, std::string large_blocks = {});

// Runs the daemon until SIGTERM/SIGINT; returns a process exit code.
int run_serve(Config config, const std::string& token, const std::string& large_blocks = {});

}  // namespace proden::daemon
