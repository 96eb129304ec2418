// Scheduler: the fair queue of frames to run and the worker threads that run them. Frames of
// all jobs share the workers round-robin by job; a frame is queued at most once and never runs
// on two workers at once (work that arrives while it runs queues it again for when it ends); a
// paused job keeps its queue but is skipped until resumed; a frame can be queued for later (retry
// back-off, on the given Clock). Thread-safe; it never calls the run function with its lock held,
// so callers may hold their own lock while calling it. No exception leaves a worker: a run that
// throws is logged, counted (proden_errors_total{kind="internal"}) and retried after a back-off.
#pragma once

#include <chrono>
#include <condition_variable>
#include <deque>
#include <functional>
#include <map>
#include <mutex>
#include <optional>
#include <set>
#include <string>
#include <thread>
#include <utility>
#include <vector>

#include "daemon/clock.hpp"
#include "daemon/metrics.hpp"

namespace proden::daemon {

class Scheduler {
 public:
  using Run = std::function<void(const std::string& job, long frame)>;
  // `metrics` (optional) receives the gauges proden_queue_depth and proden_frames_in_progress.
  Scheduler(int workers, Run run, Metrics* metrics = nullptr, const Clock& clock = steady_clock());
  ~Scheduler();
  Scheduler(const Scheduler&) = delete;
  Scheduler& operator=(const Scheduler&) = delete;

  // Called on a worker, without the lock, once the scheduler has stayed idle for `delay` (on its
  // Clock) after a run (idle: the wait_idle condition, nothing runs and no frame of an active job
  // is ready). A run that starts within the delay postpones the call to the idle time after it,
  // so a daemon fed steadily never calls it. Set before start().
  void on_idle(std::function<void()> hook,
               std::chrono::milliseconds delay = std::chrono::milliseconds(0)) {
    on_idle_ = std::move(hook);
    idle_delay_ = delay;
  }

  void start();
  // Stops taking frames: queued frames stay queued, running ones finish; joins the workers.
  void stop();
  void request_stop();  // the first half of stop(): no frame starts after it returns

  // Queues (job, frame) unless it is queued already; if it is running, it runs again after.
  // With a delay, the frame becomes ready only then (an earlier request wins).
  void enqueue(const std::string& job, long frame,
               std::chrono::milliseconds delay = std::chrono::milliseconds(0));
  void set_paused(const std::string& job, bool paused);
  void remove_job(const std::string& job);  // drops its queued frames (running ones finish)

  bool busy(const std::string& job, long frame) const;  // queued (now or later) or running
  // Housekeeping on (job, frame) done by the caller as if it were a run of the frame, only while
  // the scheduler is idle (the wait_idle condition) and the frame is neither queued nor waiting
  // for its time: true if taken, and then nothing runs the frame until release(). Work that
  // arrives meanwhile runs on the other workers; the frame's own runs after release(). The daemon
  // compresses its published images this way from the idle hook (docs/api.md, output.compression).
  bool claim(const std::string& job, long frame);
  void release(const std::string& job, long frame);
  std::size_t queued() const;
  int running() const;
  // Blocks until nothing runs and no frame of an active job is ready (frames waiting for a
  // later time do not count); false on timeout.
  bool wait_idle(int timeout_ms);

 private:
  using Key = std::pair<std::string, long>;
  using TimePoint = Clock::time_point;
  struct FrameState {
    bool queued = false, running = false, again = false;
    bool delayed = false;
    TimePoint due{};        // when delayed: when it becomes ready
    TimePoint again_due{};  // when again: when it becomes ready after the run
    int crashes = 0;        // consecutive runs that threw
  };
  struct JobQueue {
    std::deque<long> ready;
    bool in_rotation = false;
    bool paused = false;
  };
  void worker();
  void finish_locked(const std::string& job, long frame, bool crashed);  // a run ended; mu_ held
  void push(const std::string& job, long frame, FrameState& st);         // mu_ held
  void schedule(const Key& key, FrameState& st, TimePoint due);          // mu_ held
  void promote_due();                                                    // mu_ held
  void update_gauges();                                                  // mu_ held
  bool idle_locked() const;  // the wait_idle condition; mu_ held

  int workers_count_;
  Run run_;
  std::function<void()> on_idle_;
  std::chrono::milliseconds idle_delay_{0};
  std::optional<TimePoint> idle_due_;  // when the idle hook is due (set when a run ends idle)
  Metrics* metrics_;
  const Clock& clock_;
  mutable std::mutex mu_;
  std::condition_variable cv_, idle_cv_;
  std::map<Key, FrameState> frames_;
  std::set<std::pair<TimePoint, Key>> delayed_;  // frames waiting for their time
  std::map<std::string, JobQueue> jobs_;
  std::deque<std::string> rotation_;  // jobs with ready frames, served round-robin
  std::vector<std::thread> workers_;
  bool stopping_ = false;
  int running_ = 0;
};

}  // namespace proden::daemon
