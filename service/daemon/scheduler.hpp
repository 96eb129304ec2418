// Scheduler: the fair queue of frames to run and the worker threads that run them. Frames of
// all jobs share the workers round-robin by job; a frame is queued at most once and never runs
// on two workers at once (work that arrives while it runs queues it again for when it ends); a
// paused job keeps its queue but is skipped until resumed. Thread-safe; it never calls the run
// function with its lock held, so callers may hold their own lock while calling it.
#pragma once

#include <condition_variable>
#include <deque>
#include <functional>
#include <map>
#include <mutex>
#include <string>
#include <thread>
#include <utility>
#include <vector>

#include "daemon/metrics.hpp"

namespace proden::daemon {

class Scheduler {
 public:
  using Run = std::function<void(const std::string& job, long frame)>;
  // `metrics` (optional) receives the gauges proden_queue_depth, proden_frames_in_progress and
  // proden_worker_threads and the counter proden_worker_busy_seconds_total.
  Scheduler(int workers, Run run, Metrics* metrics = nullptr);
  ~Scheduler();
  Scheduler(const Scheduler&) = delete;
  Scheduler& operator=(const Scheduler&) = delete;

  void start();
  // Stops taking frames: queued frames stay queued, running ones finish; joins the workers.
  void stop();
  void request_stop();  // the first half of stop(): no frame starts after it returns

  // Queues (job, frame) unless it is queued already; if it is running, it runs again after.
  void enqueue(const std::string& job, long frame);
  void set_paused(const std::string& job, bool paused);
  void remove_job(const std::string& job);  // drops its queued frames (running ones finish)

  bool busy(const std::string& job, long frame) const;  // queued or running
  std::size_t queued() const;
  int running() const;
  // Blocks until nothing runs and no frame of an active job is queued; false on timeout.
  bool wait_idle(int timeout_ms);

 private:
  struct FrameState {
    bool queued = false, running = false, again = false;
  };
  struct JobQueue {
    std::deque<long> ready;
    bool in_rotation = false;
    bool paused = false;
  };
  void worker();
  void push(const std::string& job, long frame, FrameState& st);  // mu_ held
  void update_gauges();                                           // mu_ held

  int workers_count_;
  Run run_;
  Metrics* metrics_;
  mutable std::mutex mu_;
  std::condition_variable cv_, idle_cv_;
  std::map<std::pair<std::string, long>, FrameState> frames_;
  std::map<std::string, JobQueue> jobs_;
  std::deque<std::string> rotation_;  // jobs with ready frames, served round-robin
  std::vector<std::thread> workers_;
  bool stopping_ = false;
  int running_ = 0;
};

}  // namespace proden::daemon
