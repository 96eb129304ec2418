#include "daemon/scheduler.hpp"

#include <algorithm>
#include <chrono>
#include <climits>

namespace proden::daemon {

Scheduler::Scheduler(int workers, Run run, Metrics* metrics)
    : workers_count_(std::max(1, workers)), run_(std::move(run)), metrics_(metrics) {}

Scheduler::~Scheduler() {
  stop();
}

void Scheduler::start() {
  std::lock_guard lock(mu_);
  stopping_ = false;
  for (int i = 0; i < workers_count_; ++i) workers_.emplace_back([this] { worker(); });
  if (metrics_) metrics_->set("proden_worker_threads", workers_count_);
}

void Scheduler::request_stop() {
  {
    std::lock_guard lock(mu_);
    stopping_ = true;
  }
  cv_.notify_all();
}

void Scheduler::stop() {
  request_stop();
  for (auto& t : workers_) {
    if (t.joinable()) t.join();
  }
  workers_.clear();
}

void Scheduler::push(const std::string& job, long frame, FrameState& st) {
  st.queued = true;
  JobQueue& q = jobs_[job];
  q.ready.push_back(frame);
  if (!q.in_rotation && !q.paused) {
    q.in_rotation = true;
    rotation_.push_back(job);
  }
  update_gauges();
  cv_.notify_one();
}

void Scheduler::enqueue(const std::string& job, long frame) {
  std::lock_guard lock(mu_);
  FrameState& st = frames_[{job, frame}];
  if (st.running) {
    st.again = true;
    return;
  }
  if (st.queued) return;
  push(job, frame, st);
}

void Scheduler::set_paused(const std::string& job, bool paused) {
  std::lock_guard lock(mu_);
  JobQueue& q = jobs_[job];
  q.paused = paused;
  if (!paused && !q.ready.empty() && !q.in_rotation) {
    q.in_rotation = true;
    rotation_.push_back(job);
    cv_.notify_one();
  }
}

void Scheduler::remove_job(const std::string& job) {
  std::lock_guard lock(mu_);
  jobs_.erase(job);
  std::erase(rotation_, job);
  for (auto it = frames_.lower_bound({job, LONG_MIN});
       it != frames_.end() && it->first.first == job;) {
    if (it->second.running) {
      it->second.queued = it->second.again = false;
      ++it;
    } else {
      it = frames_.erase(it);
    }
  }
  update_gauges();
  idle_cv_.notify_all();
}

bool Scheduler::busy(const std::string& job, long frame) const {
  std::lock_guard lock(mu_);
  auto it = frames_.find({job, frame});
  return it != frames_.end() && (it->second.queued || it->second.running || it->second.again);
}

std::size_t Scheduler::queued() const {
  std::lock_guard lock(mu_);
  std::size_t n = 0;
  for (const auto& [id, q] : jobs_) n += q.ready.size();
  return n;
}

int Scheduler::running() const {
  std::lock_guard lock(mu_);
  return running_;
}

bool Scheduler::wait_idle(int timeout_ms) {
  std::unique_lock lock(mu_);
  return idle_cv_.wait_for(lock, std::chrono::milliseconds(timeout_ms),
                           [this] { return running_ == 0 && rotation_.empty(); });
}

void Scheduler::update_gauges() {
  if (!metrics_) return;
  std::size_t queued = 0;
  for (const auto& [id, q] : jobs_) queued += q.ready.size();
  metrics_->set("proden_queue_depth", static_cast<double>(queued));
  metrics_->set("proden_frames_in_progress", running_);
}

void Scheduler::worker() {
  for (;;) {
    std::string job;
    long frame = 0;
    {
      std::unique_lock lock(mu_);
      cv_.wait(lock, [this] { return stopping_ || !rotation_.empty(); });
      if (stopping_) return;
      job = rotation_.front();
      rotation_.pop_front();
      auto it = jobs_.find(job);
      if (it == jobs_.end()) continue;
      JobQueue& q = it->second;
      q.in_rotation = false;
      if (q.paused || q.ready.empty()) continue;
      frame = q.ready.front();
      q.ready.pop_front();
      if (!q.ready.empty()) {  // round-robin: back of the line
        q.in_rotation = true;
        rotation_.push_back(job);
      }
      FrameState& st = frames_[{job, frame}];
      st.queued = false;
      st.running = true;
      ++running_;
      update_gauges();
    }
    const auto t0 = std::chrono::steady_clock::now();
    run_(job, frame);
    if (metrics_) {
      metrics_->inc("proden_worker_busy_seconds_total", {},
                    std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count());
    }
    {
      std::lock_guard lock(mu_);
      --running_;
      auto it = frames_.find({job, frame});
      if (it != frames_.end()) {
        it->second.running = false;
        if (it->second.again && jobs_.count(job)) {
          it->second.again = false;
          push(job, frame, it->second);
        } else if (!it->second.queued) {
          frames_.erase(it);
        }
      }
      update_gauges();
    }
    idle_cv_.notify_all();
  }
}

}  // namespace proden::daemon
