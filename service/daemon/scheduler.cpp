#include "daemon/scheduler.hpp"

#include <spdlog/spdlog.h>

#include <algorithm>
#include <climits>

namespace proden::daemon {

const Clock& steady_clock() {
  static const SteadyClock clock;
  return clock;
}

Scheduler::Scheduler(int workers, Run run, Metrics* metrics, const Clock& clock)
    : workers_count_(std::max(1, workers)),
      run_(std::move(run)),
      metrics_(metrics),
      clock_(clock) {}

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
  if (st.delayed) {
    delayed_.erase({st.due, {job, frame}});
    st.delayed = false;
  }
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

void Scheduler::schedule(const Key& key, FrameState& st, TimePoint due) {
  if (st.delayed) {
    if (st.due <= due) return;  // an earlier request wins
    delayed_.erase({st.due, key});
  }
  st.delayed = true;
  st.due = due;
  delayed_.insert({due, key});
  cv_.notify_one();  // a worker re-computes its wait
}

void Scheduler::promote_due() {
  const TimePoint now = clock_.now();
  while (!delayed_.empty() && delayed_.begin()->first <= now) {
    const Key key = delayed_.begin()->second;
    FrameState& st = frames_[key];
    push(key.first, key.second, st);  // removes it from delayed_
  }
}

void Scheduler::enqueue(const std::string& job, long frame, std::chrono::milliseconds delay) {
  std::lock_guard lock(mu_);
  const Key key{job, frame};
  FrameState& st = frames_[key];
  const TimePoint due = clock_.now() + delay;
  if (st.running) {
    st.again_due = st.again ? std::min(st.again_due, due) : due;
    st.again = true;
    return;
  }
  if (st.queued) return;
  if (delay.count() <= 0) {
    push(job, frame, st);
  } else {
    schedule(key, st, due);
  }
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
  std::erase_if(delayed_, [&](const auto& d) { return d.second.first == job; });
  for (auto it = frames_.lower_bound({job, LONG_MIN});
       it != frames_.end() && it->first.first == job;) {
    if (it->second.running) {
      it->second.queued = it->second.again = it->second.delayed = false;
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
  if (it == frames_.end()) return false;
  const FrameState& st = it->second;
  return st.queued || st.running || st.again || st.delayed;
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

bool Scheduler::idle_locked() const {
  // A job paused while in the rotation stays there until a worker passes it over: not work.
  return running_ == 0 && std::none_of(rotation_.begin(), rotation_.end(), [&](const auto& job) {
           const auto it = jobs_.find(job);
           return it != jobs_.end() && !it->second.paused && !it->second.ready.empty();
         });
}

bool Scheduler::wait_idle(int timeout_ms) {
  std::unique_lock lock(mu_);
  return idle_cv_.wait_for(lock, std::chrono::milliseconds(timeout_ms),
                           [this] { return idle_locked(); });
}

void Scheduler::update_gauges() {
  if (!metrics_) return;
  std::size_t queued = 0;
  for (const auto& [id, q] : jobs_) queued += q.ready.size();
  metrics_->set("proden_queue_depth", static_cast<double>(queued));
  metrics_->set("proden_frames_in_progress", running_);
}

void Scheduler::finish_locked(const std::string& job, long frame, bool crashed) {
  --running_;
  const Key key{job, frame};
  auto it = frames_.find(key);
  if (it != frames_.end()) {
    FrameState& st = it->second;
    st.running = false;
    if (crashed) {
      const int n = std::min(++st.crashes, 9);  // 1 s, 2 s, ... 256 s
      const TimePoint due = clock_.now() + std::chrono::seconds(1 << (n - 1));
      st.again_due = st.again ? std::min(st.again_due, due) : due;
      st.again = true;
    } else {
      st.crashes = 0;
    }
    if (st.again && jobs_.count(job)) {
      st.again = false;
      if (st.again_due <= clock_.now()) {
        push(job, frame, st);
      } else {
        schedule(key, st, st.again_due);
      }
    } else if (!st.queued && !st.delayed && st.crashes == 0) {
      frames_.erase(it);
    }
  }
  update_gauges();
  // Idle now: the hook is due after the delay, on whichever worker waits then (this one,
  // next time round the loop, without a delay).
  if (on_idle_ && idle_locked()) idle_due_ = clock_.now() + idle_delay_;
}

bool Scheduler::claim(const std::string& job, long frame) {
  std::lock_guard lock(mu_);
  if (stopping_ || !idle_locked()) return false;
  const auto it = frames_.find({job, frame});
  if (it != frames_.end() && (it->second.queued || it->second.delayed)) return false;
  jobs_[job];  // known, so that a run asked for meanwhile is queued at release
  FrameState& st = frames_[{job, frame}];
  st.running = true;
  ++running_;
  update_gauges();
  return true;
}

void Scheduler::release(const std::string& job, long frame) {
  {
    std::lock_guard lock(mu_);
    finish_locked(job, frame, false);
  }
  idle_cv_.notify_all();
}

void Scheduler::worker() {
  for (;;) {
    std::string job;
    long frame = 0;
    {
      std::unique_lock lock(mu_);
      for (;;) {
        promote_due();
        if (stopping_) return;
        if (!rotation_.empty()) break;
        const TimePoint now = clock_.now();
        if (idle_due_ && *idle_due_ <= now) {
          idle_due_.reset();
          if (idle_locked()) {  // else a run started meanwhile: its end sets the next due time
            lock.unlock();
            on_idle_();
            lock.lock();
          }
          continue;
        }
        if (delayed_.empty() && !idle_due_) {
          cv_.wait(lock);
        } else {
          // Until the first due time; re-read the clock at least every 100 ms, since a fake clock
          // in tests moves on its own.
          TimePoint due = delayed_.empty() ? *idle_due_ : delayed_.begin()->first;
          if (idle_due_) due = std::min(due, *idle_due_);
          cv_.wait_for(lock, std::min<Clock::time_point::duration>(due - now,
                                                                   std::chrono::milliseconds(100)));
        }
      }
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
    // No exception leaves a worker: it is logged, counted, and the frame runs again after a
    // back-off (the run function keeps its own state consistent).
    bool crashed = false;
    const auto t0 = std::chrono::steady_clock::now();
    try {
      run_(job, frame);
    } catch (const std::exception& e) {
      crashed = true;
      spdlog::error("job {} frame {}: internal error: {}", job, frame, e.what());
    } catch (...) {
      crashed = true;
      spdlog::error("job {} frame {}: internal error (unknown exception)", job, frame);
    }
    if (crashed && metrics_) metrics_->inc("proden_errors_total", "internal");
    if (metrics_) {
      metrics_->inc("proden_worker_busy_seconds_total", {},
                    std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count());
    }
    {
      std::lock_guard lock(mu_);
      finish_locked(job, frame, crashed);
    }
    idle_cv_.notify_all();
  }
}

}  // namespace proden::daemon
