// Prometheus metrics of the daemon (counters, gauges, histograms; prefix proden_, base units, no
// per-frame labels), rendered in the text exposition format for GET /metrics.
#pragma once

#include <atomic>
#include <map>
#include <mutex>
#include <string>
#include <vector>

namespace proden::daemon {

class Metrics {
 public:
  Metrics();
  void inc(const std::string& name, const std::string& label_value = {}, double by = 1.0);
  void set(const std::string& name, double value);
  void observe(const std::string& name, const std::string& label_value, double seconds);
  std::string render() const;

 private:
  struct Family {
    std::string help, type, label;         // type: counter | gauge | histogram
    std::map<std::string, double> values;  // label value -> value (counters, gauges)
    struct Hist {
      std::vector<double> counts;  // per bucket, cumulative at render time
      double sum = 0.0;
      double count = 0.0;
    };
    std::map<std::string, Hist> hists;
  };
  void declare(const std::string& name, const std::string& type, const std::string& help,
               const std::string& label = {});
  mutable std::mutex mu_;
  std::map<std::string, Family> families_;
  std::vector<double> buckets_;
};

}  // namespace proden::daemon
