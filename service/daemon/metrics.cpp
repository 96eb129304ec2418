#include "daemon/metrics.hpp"

#include <cmath>
#include <sstream>

namespace proden::daemon {

Metrics::Metrics()
    : buckets_{0.001, 0.0025, 0.005, 0.01, 0.025, 0.05, 0.1, 0.25, 0.5, 1, 2.5, 5, 10, 30, 60} {
  declare("proden_passes_ingested_total", "counter", "Passes accumulated into frames");
  declare("proden_ingested_bytes_total", "counter", "Bytes of pass files accumulated");
  declare("proden_frame_updates_total", "counter", "Frame versions published");
  declare("proden_frames_converged_total", "counter",
          "Frames that met their job's target with confidence (docs/api.md)");
  declare("proden_frames_unconverged_total", "counter",
          "Converged frames whose later version missed the target with confidence");
  declare("proden_uploads_total", "counter", "Passes received by HTTP upload");
  declare("proden_errors_total", "counter", "Errors by kind", "kind");
  declare("proden_http_requests_total", "counter", "HTTP requests answered, by status class",
          "code");
  declare("proden_stage_duration_seconds", "histogram",
          "Duration of processing stages (read, accumulate, persist, process, publish)", "stage");
  declare("proden_queue_depth", "gauge", "Frames waiting for a worker");
  declare("proden_frames_in_progress", "gauge", "Frames being processed");
  declare("proden_worker_threads", "gauge", "Workers that process frames");
  declare(
      "proden_worker_busy_seconds_total", "counter",
      "Seconds workers spent processing frames (its rate / proden_worker_threads = utilisation)");
  declare("proden_jobs", "gauge", "Jobs known to the daemon");
  declare("proden_resident_frames", "gauge",
          "Frames whose accumulated state is kept in memory between updates");
  declare("proden_resident_bytes", "gauge", "Bytes of the frames' states kept in memory");
  declare("proden_resident_budget_bytes", "gauge",
          "Memory for resident states (max_resident_bytes, or a quarter of usable memory)");
  declare("proden_evictions_total", "counter",
          "Resident states dropped for max_resident_frames or max_resident_bytes (reloaded from "
          "their state file at their frame's next update)");
  declare("proden_publish_uncompressed_total", "counter",
          "Versions written uncompressed by output.compression auto, to be compressed when idle");
  declare("proden_publish_compressed_later_total", "counter",
          "Versions written uncompressed (output.compression auto) and compressed once the daemon "
          "was idle");
  declare("proden_sse_clients", "gauge", "Connected Server-Sent Events clients");
  declare("proden_http_connections", "gauge", "Open HTTP connections");
}

void Metrics::declare(const std::string& name, const std::string& type, const std::string& help,
                      const std::string& label) {
  Family f;
  f.help = help;
  f.type = type;
  f.label = label;
  if (label.empty() && type != "histogram") f.values[""] = 0.0;
  families_.emplace(name, std::move(f));
}

void Metrics::inc(const std::string& name, const std::string& label_value, double by) {
  std::lock_guard lock(mu_);
  auto it = families_.find(name);
  if (it != families_.end()) it->second.values[label_value] += by;
}

void Metrics::set(const std::string& name, double value) {
  std::lock_guard lock(mu_);
  auto it = families_.find(name);
  if (it != families_.end()) it->second.values[""] = value;
}

void Metrics::observe(const std::string& name, const std::string& label_value, double seconds) {
  std::lock_guard lock(mu_);
  auto it = families_.find(name);
  if (it == families_.end()) return;
  auto& h = it->second.hists[label_value];
  if (h.counts.empty()) h.counts.assign(buckets_.size(), 0.0);
  for (std::size_t i = 0; i < buckets_.size(); ++i) {
    if (seconds <= buckets_[i]) h.counts[i] += 1.0;
  }
  h.sum += seconds;
  h.count += 1.0;
}

namespace {

std::string num(double v) {
  if (std::isinf(v)) return v > 0 ? "+Inf" : "-Inf";
  std::ostringstream os;
  os.precision(17);
  os << v;
  return os.str();
}

}  // namespace

std::string Metrics::render() const {
  std::lock_guard lock(mu_);
  std::ostringstream os;
  for (const auto& [name, f] : families_) {
    os << "# HELP " << name << " " << f.help << "\n# TYPE " << name << " " << f.type << "\n";
    if (f.type == "histogram") {
      for (const auto& [lv, h] : f.hists) {
        const std::string lbl = f.label + "=\"" + lv + "\"";
        for (std::size_t i = 0; i < buckets_.size(); ++i) {
          os << name << "_bucket{" << lbl << ",le=\"" << num(buckets_[i]) << "\"} "
             << num(h.counts[i]) << "\n";
        }
        os << name << "_bucket{" << lbl << ",le=\"+Inf\"} " << num(h.count) << "\n";
        os << name << "_sum{" << lbl << "} " << num(h.sum) << "\n";
        os << name << "_count{" << lbl << "} " << num(h.count) << "\n";
      }
      continue;
    }
    for (const auto& [lv, v] : f.values) {
      if (f.label.empty()) {
        os << name << " " << num(v) << "\n";
      } else {
        os << name << "{" << f.label << "=\"" << lv << "\"} " << num(v) << "\n";
      }
    }
  }
  return os.str();
}

}  // namespace proden::daemon
