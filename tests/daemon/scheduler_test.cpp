// Scheduler: round-robin fairness by job, one run per frame at a time, coalescing, pause.
#include <catch2/catch.hpp>

#include <atomic>
#include <chrono>
#include <condition_variable>
#include <mutex>
#include <string>
#include <thread>
#include <vector>

#include "daemon/scheduler.hpp"
#include "daemon_support.hpp"

using namespace proden::daemon;

namespace {

// Records the runs in order.
struct Log {
  std::mutex mu;
  std::vector<std::string> runs;
  void add(const std::string& job, long frame) {
    std::lock_guard lock(mu);
    runs.push_back(job + std::to_string(frame));
  }
  std::vector<std::string> get() {
    std::lock_guard lock(mu);
    return runs;
  }
};

// A gate a run waits at until opened.
struct Gate {
  std::mutex mu;
  std::condition_variable cv;
  bool open = false;
  int waiting = 0;
  void wait() {
    std::unique_lock lock(mu);
    ++waiting;
    cv.notify_all();
    cv.wait(lock, [this] { return open; });
  }
  void wait_for_waiter() {
    std::unique_lock lock(mu);
    cv.wait(lock, [this] { return waiting > 0; });
  }
  void release() {
    std::lock_guard lock(mu);
    open = true;
    cv.notify_all();
  }
};

// Polls `done` for up to 10 s: for what a worker does after the run the test waits on.
template <class P>
void wait_until(P done) {
  for (int i = 0; i < 1000 && !done(); ++i) {
    std::this_thread::sleep_for(std::chrono::milliseconds(10));
  }
}

}  // namespace

TEST_CASE("Scheduler: jobs take turns (round-robin)", "[daemon][scheduler]") {
  Log log;
  Scheduler s(1, [&](const std::string& j, long f) { log.add(j, f); });
  for (long f = 1; f <= 4; ++f) s.enqueue("a", f);
  for (long f = 1; f <= 2; ++f) s.enqueue("b", f);
  CHECK(s.queued() == 6);
  s.start();
  REQUIRE(s.wait_idle(10000));
  CHECK(log.get() == std::vector<std::string>{"a1", "b1", "a2", "b2", "a3", "a4"});
  CHECK(s.queued() == 0);
}

TEST_CASE("Scheduler: the idle hook runs once the queue drains, not between runs",
          "[daemon][scheduler]") {
  // The engine returns freed memory to the system from this hook: a busy daemon keeps it for
  // the next run, an idle one gives it back.
  Log log;
  Gate gate;
  std::mutex mu;
  std::vector<std::size_t> runs_seen;  // runs done at each idle call
  Scheduler s(2, [&](const std::string& j, long f) {
    if (j == "gated") gate.wait();
    log.add(j, f);
  });
  s.on_idle([&] {
    std::lock_guard lock(mu);
    runs_seen.push_back(log.get().size());
  });
  const auto idle_calls = [&] {
    std::lock_guard lock(mu);
    return runs_seen;
  };
  for (long f = 1; f <= 4; ++f) s.enqueue("a", f);
  s.enqueue("gated", 1);
  s.start();
  gate.wait_for_waiter();
  // The other worker drains "a" while "gated" runs: nothing is idle yet.
  wait_until([&] { return log.get().size() >= 4; });
  REQUIRE(log.get().size() == 4);
  CHECK(idle_calls().empty());
  gate.release();
  wait_until([&] { return !idle_calls().empty(); });
  CHECK(idle_calls() == std::vector<std::size_t>{5});
  s.enqueue("a", 9);
  wait_until([&] { return idle_calls().size() >= 2; });
  CHECK(idle_calls() == std::vector<std::size_t>{5, 6});
}

TEST_CASE("Scheduler: with a delay, the idle hook waits until the scheduler has stayed idle",
          "[daemon][scheduler]") {
  // An idle time shorter than the delay (the next pass lands soon) keeps the freed memory for
  // the run that follows; the hook runs once the scheduler has been idle for the whole delay.
  using std::chrono::milliseconds;
  proden::test::FakeClock clock;
  Log log;
  std::atomic<int> idle_calls{0};
  Scheduler s(
      2, [&](const std::string& j, long f) { log.add(j, f); }, nullptr, clock);
  s.on_idle([&] { ++idle_calls; }, milliseconds(1000));
  s.start();
  // Workers re-read the (fake) clock at least every 100 ms; 300 ms of real time covers that.
  const auto settle = [] { std::this_thread::sleep_for(milliseconds(300)); };
  s.enqueue("a", 1);
  REQUIRE(s.wait_idle(10000));  // idle at t0: the hook is due at t0 + 1000
  clock.advance(milliseconds(600));
  settle();
  CHECK(idle_calls == 0);
  s.enqueue("a", 2);  // work within the delay: the hook is due 1000 after it ends (t0 + 1600)
  REQUIRE(s.wait_idle(10000));
  clock.advance(milliseconds(500));  // t0 + 1100: past the first due time, not the second
  settle();
  CHECK(idle_calls == 0);
  clock.advance(milliseconds(600));  // t0 + 1700
  wait_until([&] { return idle_calls > 0; });
  CHECK(idle_calls == 1);
  clock.advance(milliseconds(5000));
  settle();
  CHECK(idle_calls == 1);  // once per idle time
  CHECK(log.get() == std::vector<std::string>{"a1", "a2"});
}

TEST_CASE("Scheduler: a job paused while queued does not keep the scheduler from idling",
          "[daemon][scheduler]") {
  Log log;
  Gate gate;
  std::atomic<int> idle_calls{0};
  Scheduler s(1, [&](const std::string& j, long f) {
    if (j == "gated") gate.wait();
    log.add(j, f);
  });
  s.on_idle([&] { ++idle_calls; });
  s.enqueue("gated", 1);
  s.enqueue("a", 1);
  s.start();
  gate.wait_for_waiter();
  s.set_paused("a", true);  // "a" is in the rotation behind the running frame
  gate.release();
  wait_until([&] { return idle_calls > 0; });
  CHECK(idle_calls == 1);
  REQUIRE(s.wait_idle(10000));
  CHECK(log.get() == std::vector<std::string>{"gated1"});
  CHECK(s.busy("a", 1));
}

TEST_CASE("Scheduler: a frame is queued once and re-runs once after work arrives mid-run",
          "[daemon][scheduler]") {
  Log log;
  Gate gate;
  std::atomic<int> concurrent{0}, max_concurrent{0};
  Scheduler s(2, [&](const std::string& j, long f) {
    const int now = ++concurrent;
    max_concurrent = std::max(max_concurrent.load(), now);
    if (log.get().empty()) {
      log.add(j, f);
      gate.wait();
    } else {
      log.add(j, f);
    }
    --concurrent;
  });
  s.start();
  s.enqueue("a", 1);
  gate.wait_for_waiter();
  CHECK(s.busy("a", 1));
  for (int i = 0; i < 5; ++i) s.enqueue("a", 1);  // while it runs: coalesce into one more run
  gate.release();
  REQUIRE(s.wait_idle(10000));
  CHECK(log.get() == std::vector<std::string>{"a1", "a1"});
  CHECK(max_concurrent == 1);
  CHECK_FALSE(s.busy("a", 1));
}

TEST_CASE("Scheduler: a paused job keeps its queue until resumed", "[daemon][scheduler]") {
  Log log;
  Scheduler s(1, [&](const std::string& j, long f) { log.add(j, f); });
  s.set_paused("a", true);
  s.enqueue("a", 1);
  s.enqueue("b", 1);
  s.start();
  REQUIRE(s.wait_idle(10000));
  CHECK(log.get() == std::vector<std::string>{"b1"});
  CHECK(s.busy("a", 1));
  s.set_paused("a", false);
  REQUIRE(s.wait_idle(10000));
  CHECK(log.get() == std::vector<std::string>{"b1", "a1"});
}

TEST_CASE("Scheduler: removing a job drops its queued frames", "[daemon][scheduler]") {
  Log log;
  Scheduler s(1, [&](const std::string& j, long f) { log.add(j, f); });
  s.enqueue("a", 1);
  s.enqueue("a", 2);
  s.enqueue("b", 1);
  s.remove_job("a");
  CHECK_FALSE(s.busy("a", 1));
  s.start();
  REQUIRE(s.wait_idle(10000));
  CHECK(log.get() == std::vector<std::string>{"b1"});
}

TEST_CASE("Scheduler: stop lets the running frame finish and leaves the queue",
          "[daemon][scheduler]") {
  Log log;
  Gate gate;
  Scheduler s(1, [&](const std::string& j, long f) {
    log.add(j, f);
    if (f == 1) gate.wait();
  });
  s.start();
  s.enqueue("a", 1);
  gate.wait_for_waiter();
  s.enqueue("a", 2);
  s.request_stop();
  gate.release();
  s.stop();
  CHECK(log.get() == std::vector<std::string>{"a1"});
  CHECK(s.busy("a", 2));
}

TEST_CASE("Scheduler: an exception never leaves a worker; the frame is retried later",
          "[daemon][scheduler][regression]") {
  Log log;
  proden::test::FakeClock clock;
  Metrics metrics;
  std::atomic<int> calls{0};
  Scheduler s(
      1,
      [&](const std::string& j, long f) {
        log.add(j, f);
        if (calls++ == 0) throw std::runtime_error("escaped (simulated)");
      },
      &metrics, clock);
  s.start();
  s.enqueue("a", 1);
  REQUIRE(s.wait_idle(10000));
  CHECK(log.get().size() == 1);
  CHECK(s.busy("a", 1));  // waiting for its retry
  CHECK(metrics.render().find("proden_errors_total{kind=\"internal\"} 1") != std::string::npos);
  s.enqueue("b", 1);  // the worker still works
  REQUIRE(proden::test::eventually([&] { return log.get().size() == 2; }));
  clock.advance(std::chrono::minutes(10));
  REQUIRE(proden::test::eventually([&] { return log.get().size() == 3; }));
  CHECK(log.get() == std::vector<std::string>{"a1", "b1", "a1"});
}

TEST_CASE("Scheduler: a frame queued for later runs when its time comes", "[daemon][scheduler]") {
  Log log;
  proden::test::FakeClock clock;
  Scheduler s(
      1, [&](const std::string& j, long f) { log.add(j, f); }, nullptr, clock);
  s.start();
  s.enqueue("a", 1, std::chrono::seconds(30));
  s.enqueue("a", 2);
  REQUIRE(proden::test::eventually([&] { return log.get().size() == 1; }));
  std::this_thread::sleep_for(std::chrono::milliseconds(250));
  CHECK(log.get() == std::vector<std::string>{"a2"});
  CHECK(s.busy("a", 1));
  clock.advance(std::chrono::seconds(31));
  REQUIRE(proden::test::eventually([&] { return log.get().size() == 2; }));
  s.enqueue("a", 3, std::chrono::seconds(30));
  s.enqueue("a", 3);  // now wins over later
  REQUIRE(proden::test::eventually([&] { return log.get().size() == 3; }));
}

TEST_CASE("Scheduler: claim takes a frame for housekeeping only while idle, and excludes its runs",
          "[daemon][scheduler]") {
  Gate gate;
  Log log;
  Scheduler s(2, [&](const std::string& j, long f) {
    if (j == "gated") gate.wait();
    log.add(j, f);
  });
  s.start();
  s.enqueue("gated", 1);
  gate.wait_for_waiter();
  CHECK_FALSE(s.claim("a", 1));  // something runs: not idle
  gate.release();
  REQUIRE(s.wait_idle(10000));
  s.set_paused("p", true);
  s.enqueue("p", 1);             // queued, but its job is paused: the scheduler is still idle
  CHECK_FALSE(s.claim("p", 1));  // the frame itself is queued
  REQUIRE(s.claim("a", 1));
  CHECK(s.busy("a", 1));
  CHECK(s.running() == 1);
  CHECK_FALSE(s.wait_idle(50));  // the claim counts as a run
  CHECK_FALSE(s.claim("a", 2));  // one claim at a time: not idle
  // Work that arrives meanwhile: another frame runs on a free worker; the claimed one waits.
  s.enqueue("b", 1);
  s.enqueue("a", 1);
  REQUIRE(proden::test::eventually([&] { return log.get().size() == 2; }));
  std::this_thread::sleep_for(std::chrono::milliseconds(200));
  CHECK(log.get() == std::vector<std::string>{"gated1", "b1"});
  s.release("a", 1);
  REQUIRE(proden::test::eventually([&] { return log.get().size() == 3; }));
  CHECK(log.get().back() == "a1");
  REQUIRE(s.wait_idle(10000));
  CHECK_FALSE(s.busy("a", 1));
  s.request_stop();
  CHECK_FALSE(s.claim("a", 1));  // stopping: no new housekeeping
}
