// `proden wait`: blocks until a frame of a job on a running `proden serve` is converged or has a
// version above K, for farm scripts (docs/api.md, "Waiting from a script": exit codes).
#pragma once

#include <string>

namespace proden::cli {

struct WaitOptions {
  std::string url;  // http://host:port (default: $PRODEN_URL or http://127.0.0.1:8080)
  std::string token_file;
  std::string job;
  long frame = -1;
  std::string until = "converged";  // "converged" or "version>K"
  double timeout = 0.0;             // seconds; 0 = no limit
  bool json = false;
  bool quiet = false;
};

// Exit codes beyond commands.hpp's ExitCode.
enum WaitExit : int {
  kWaitTimeout = 4,      // the condition did not hold within --timeout
  kWaitNoJob = 5,        // the job does not exist or was deleted
  kWaitUnreachable = 6,  // the daemon could not be reached (or kept failing) until the timeout
};

int run_wait(const WaitOptions& o);

}  // namespace proden::cli
