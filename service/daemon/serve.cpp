#include "daemon/serve.hpp"

#include <fcntl.h>
#include <poll.h>
#include <signal.h>
#include <spdlog/spdlog.h>
#include <sys/file.h>
#include <sys/resource.h>
#include <sys/signalfd.h>
#include <sys/stat.h>
#include <unistd.h>

#include <atomic>
#include <cerrno>
#include <climits>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <memory>
#include <thread>

#include "daemon/api.hpp"
#include "daemon/config.hpp"
#include "daemon/engine.hpp"
#include "daemon/events.hpp"
#include "daemon/files.hpp"
#include "daemon/http_server.hpp"
#include "daemon/memory.hpp"
#include "daemon/metrics.hpp"

namespace proden::daemon {

namespace fs = std::filesystem;

namespace {

// SIGTERM/SIGINT are read from a signalfd by the thread that waits in run_serve(). Every thread
// blocks them, so the kernel keeps a stop signal pending for that fd instead of running a handler
// on whichever thread it picks; the executable blocks them before any library starts a thread
// (proden_block_stop_signals() in cli/main.cpp: OpenBLAS starts its pool when it is loaded).
// Under ThreadSanitizer, which defers a handler to the thread's next intercepted call, a handler
// could lose a SIGTERM sent just after start-up: the daemon then never drained (1 stop in 40-75,
// 2026-12-07). The handler stays as the fallback for a thread that did not inherit the mask (an
// executable that does not block early): it writes the signal's number to the drain pipe.
int g_signal_fd = -1;
int g_drain_read = -1;
std::atomic<int> g_drain_write{-1};
static_assert(std::atomic<int>::is_always_lock_free);  // async-signal-safe

extern "C" void on_stop_signal(int sig) {
  const int saved = errno;
  const unsigned char c = static_cast<unsigned char>(sig);
  [[maybe_unused]] const ssize_t n = ::write(g_drain_write.load(), &c, 1);
  errno = saved;
}

sigset_t stop_signals() {
  sigset_t set;
  sigemptyset(&set);
  sigaddset(&set, SIGTERM);
  sigaddset(&set, SIGINT);
  return set;
}

// Blocks SIGTERM/SIGINT on this thread (the daemon's threads inherit it), opens the signalfd and
// the drain pipe and installs the fallback handler; false when the fd or pipe cannot be made.
bool catch_stop_signals() {
  const sigset_t set = stop_signals();
  ::pthread_sigmask(SIG_BLOCK, &set, nullptr);
  int fds[2];
  if (::pipe2(fds, O_CLOEXEC | O_NONBLOCK) != 0) return false;
  g_drain_read = fds[0];
  g_drain_write.store(fds[1]);
  g_signal_fd = ::signalfd(-1, &set, SFD_CLOEXEC | SFD_NONBLOCK);
  if (g_signal_fd < 0) return false;
  struct sigaction sa {};
  sa.sa_handler = on_stop_signal;
  sigemptyset(&sa.sa_mask);
  sa.sa_flags = SA_RESTART;
  ::sigaction(SIGTERM, &sa, nullptr);
  ::sigaction(SIGINT, &sa, nullptr);
  return true;
}

// Wakes wait_stop_signal() with 0, no signal's number: the drain has ended.
void notify_drained() {
  const unsigned char c = 0;
  [[maybe_unused]] const ssize_t n = ::write(g_drain_write.load(), &c, 1);
}

// Blocks until a stop signal was taken (returns its number) or notify_drained() ran (0).
int wait_stop_signal() {
  for (;;) {
    pollfd p[2] = {{g_signal_fd, POLLIN, 0}, {g_drain_read, POLLIN, 0}};
    if (::poll(p, 2, -1) <= 0) continue;  // EINTR
    signalfd_siginfo info{};
    if ((p[0].revents & POLLIN) && ::read(g_signal_fd, &info, sizeof info) == sizeof info) {
      return static_cast<int>(info.ssi_signo);
    }
    unsigned char c = 0;
    if ((p[1].revents & POLLIN) && ::read(g_drain_read, &c, 1) == 1) return c;
  }
}

struct ServeFlags {
  std::string config_file, bind, state_dir, token_file, log_level;
  std::vector<std::string> roots;
  int port = -1, workers = 0, poll_ms = 0, settle_ms = 0;
  std::string large_blocks;  // not a flag: add_serve_command's argument
  bool print_config = false;
};

std::string read_token(const std::string& path) {
  std::ifstream in(path);
  if (!in) throw std::runtime_error("cannot read token file " + path);
  std::string t((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
  while (!t.empty() && std::isspace(static_cast<unsigned char>(t.back()))) t.pop_back();
  while (!t.empty() && std::isspace(static_cast<unsigned char>(t.front()))) t.erase(0, 1);
  if (t.size() < 16)
    throw std::runtime_error("token in " + path + " is shorter than 16 characters");
  struct stat st {};
  if (::stat(path.c_str(), &st) == 0 && (st.st_mode & 0077)) {
    spdlog::warn("token file {} is readable by group/others (chmod 600 it)", path);
  }
  return t;
}

int serve_main(const ServeFlags& f) {
  Config c;
  try {
    if (!f.config_file.empty()) load_config_file(c, f.config_file);
  } catch (const std::exception& e) {
    spdlog::error("{}", e.what());
    return 2;
  }
  if (!f.bind.empty()) c.bind = f.bind;
  if (f.port >= 0) c.port = f.port;
  if (!f.state_dir.empty()) c.state_dir = f.state_dir;
  if (!f.roots.empty()) c.allowed_roots = f.roots;
  if (!f.token_file.empty()) c.token_file = f.token_file;
  if (!f.log_level.empty()) c.log_level = f.log_level;
  if (f.workers > 0) c.worker_threads = f.workers;
  if (f.poll_ms > 0) c.watch.poll_interval_ms = f.poll_ms;
  if (f.settle_ms > 0) c.watch.settle_ms = f.settle_ms;
  if (f.print_config) {
    std::printf("%s\n", to_json(c).dump(2).c_str());
    return 0;
  }
  std::string token;
  try {
    if (!c.token_file.empty()) token = read_token(c.token_file);
  } catch (const std::exception& e) {
    spdlog::error("{}", e.what());
    return 2;
  }
  return run_serve(c, token, f.large_blocks);
}

}  // namespace

void add_serve_command(CLI::App& app, std::string large_blocks) {
  auto flags = std::make_shared<ServeFlags>();
  flags->large_blocks = std::move(large_blocks);
  auto* s = app.add_subcommand("serve", "Run the daemon: watch, accumulate, publish, serve HTTP");
  s->add_option("--config", flags->config_file, "JSON config file (flags override it)");
  s->add_option("--bind", flags->bind, "Address to bind (default 127.0.0.1)");
  s->add_option("--port", flags->port, "TCP port (0 = pick a free one)")
      ->check(CLI::Range(0, 65535));
  s->add_option("--state-dir", flags->state_dir, "State directory (jobs, frame state)");
  s->add_option("--allow-root", flags->roots, "Directory watched/output paths must lie in");
  s->add_option("--token-file", flags->token_file, "File holding the bearer token");
  s->add_option("--workers", flags->workers, "Frames processed concurrently")
      ->check(CLI::PositiveNumber);
  s->add_option("--poll-interval-ms", flags->poll_ms, "Directory scan interval")
      ->check(CLI::PositiveNumber);
  s->add_option("--settle-ms", flags->settle_ms, "Stability time before a file is read")
      ->check(CLI::PositiveNumber);
  s->add_option("--log-level", flags->log_level, "trace, debug, info, warn, error");
  s->add_flag("--print-config", flags->print_config, "Print the effective config and exit");
  s->callback([flags] {
    const int rc = serve_main(*flags);
    spdlog::shutdown();
    std::fflush(stdout);
    std::exit(rc);
  });
}

int run_serve(Config c, const std::string& token, const std::string& large_blocks) {
  spdlog::set_pattern("%Y-%m-%dT%H:%M:%S.%e proden[%t] %^%l%$: %v");
  spdlog::set_level(spdlog::level::from_str(c.log_level));
  if (c.allowed_roots.empty()) {
    spdlog::error("no allowed roots: give --allow-root DIR (watched and output paths live there)");
    return 2;
  }
  if (token.empty() && !is_loopback_address(c.bind)) {
    spdlog::error("refusing to bind {} without a token: use --token-file, or bind loopback",
                  c.bind);
    return 2;
  }
  Roots roots;
  try {
    roots = Roots(c.allowed_roots);
    fs::create_directories(c.state_dir);
    c.state_dir = fs::canonical(c.state_dir).string();
  } catch (const std::exception& e) {
    spdlog::error("{}", e.what());
    return 2;
  }
  // One daemon per state directory.
  const std::string lock_path = c.state_dir + "/lock";
  const int lock_fd = ::open(lock_path.c_str(), O_RDWR | O_CREAT | O_CLOEXEC, 0644);
  if (lock_fd < 0 || ::flock(lock_fd, LOCK_EX | LOCK_NB) != 0) {
    spdlog::error("state directory {} is in use by another proden serve", c.state_dir);
    return 1;
  }
  // Many SSE clients need descriptors.
  rlimit rl{};
  if (::getrlimit(RLIMIT_NOFILE, &rl) == 0 && rl.rlim_cur < rl.rlim_max) {
    rl.rlim_cur = rl.rlim_max;
    ::setrlimit(RLIMIT_NOFILE, &rl);
  }
  // The stop signals are blocked on every thread and read from a signalfd (catch_stop_signals),
  // so no worker or I/O call is interrupted and this thread takes them once it waits.
  if (!catch_stop_signals()) {
    spdlog::error("cannot set up the stop signals: {}", std::strerror(errno));
    return 1;
  }
  ::signal(SIGPIPE, SIG_IGN);

  // Frame-sized planes (up to 32 MiB: 1080p and below) stay in the heap while the daemon is busy,
  // so a run reuses the pages of the one before it instead of faulting ~1.2 GB in afresh (the
  // kernel zeroes every page: +14-34 % on a 1080p update, bench/RESULTS.md "Heap policy");
  // the engine returns them once the scheduler has been idle for a second (engine.cpp).
  configure_allocator(std::size_t{32} << 20, std::size_t{INT_MAX}, 4);

  Metrics metrics;
  EventHub events(c.limits.sse_history);
  Engine engine(c, roots, metrics, events);
  Api api(c, engine, roots, events, metrics, token);
  HttpServer server(c, api, events, metrics);
  unsigned short port = 0;
  try {
    engine.start();
    port = server.listen(c.bind, static_cast<unsigned short>(c.port));
  } catch (const std::exception& e) {
    spdlog::error("cannot start: {}", e.what());
    engine.stop();
    return 1;
  }
  server.run(c.io_threads);
  const std::string host = c.bind.find(':') != std::string::npos ? "[" + c.bind + "]" : c.bind;
  std::printf("listening on http://%s:%u\n", host.c_str(), port);
  std::fflush(stdout);
  spdlog::info("listening on http://{}:{} (state {}, {} worker(s), token {}{}{})", host, port,
               c.state_dir, c.worker_threads, token.empty() ? "off" : "on",
               large_blocks.empty() ? "" : ", huge pages ", large_blocks);

  const int sig = wait_stop_signal();
  spdlog::info("signal {}: draining (a second signal stops at once)", sig);
  api.set_draining();
  // The drain runs beside this thread, which waits for it or for a second stop signal (a
  // wrangler's second Ctrl-C, a stop script's escalation). That one exits at once and leaves the
  // frames in flight as kill -9 would, which loses nothing: on restart their passes are found
  // again and counted once (docs/api.md).
  std::thread drain([&] {
    engine.stop();  // finishes in-flight frames; their state is persisted as they complete
    server.stop();
    notify_drained();
  });
  if (const int second = wait_stop_signal(); second != 0) {
    spdlog::warn("signal {} while draining: exiting now, the frames in flight are left unfinished",
                 second);
    spdlog::default_logger()->flush();
    // Dies of the signal (its default action), as a process that does not drain would: a shell
    // or systemd sees 128 + the signal, and nothing runs on the way out.
    ::signal(second, SIG_DFL);
    const sigset_t set = stop_signals();
    ::pthread_sigmask(SIG_UNBLOCK, &set, nullptr);
    ::raise(second);
    ::_exit(128 + second);  // not reached
  }
  drain.join();
  spdlog::info("stopped");
  ::close(lock_fd);
  return 0;
}

}  // namespace proden::daemon
