// JSON forms of proden's reports: what a pass file holds, error metrics, a frame's accumulated
// state. Field names are part of the contract with integrations: extend, never rename.
#pragma once

#include <cmath>
#include <concepts>
#include <cstdint>
#include <limits>
#include <stdexcept>
#include <string>
#include <utility>

#include <nlohmann/json.hpp>

#include "proden/accumulator.hpp"
#include "proden/io/pass_reader.hpp"
#include "proden/metrics.hpp"

namespace proden::protocol {

nlohmann::json to_json(const io::PassInfo& info);
nlohmann::json to_json(const ErrorMetrics& m);
nlohmann::json to_json(const Layout& layout);
// Summary of a frame: size, layout, passes (with per-pass records), spp, variance source, flags.
nlohmann::json frame_summary(const FrameAccumulator& frame, const FrameEstimate& estimate);
// {"error": {"code": ..., "message": ..., "subject": ...}}
nlohmann::json error_json(std::string_view code, const std::string& message,
                          const std::string& subject = {});

std::string_view to_string(VarianceSource s);

// The number `v` holds, as T, checked: an integer type takes only a JSON integer within its
// range, a floating type only a finite number. nlohmann's get<T>() converts out-of-range numbers
// with a cast whose behaviour is undefined (1e20 as int) or wraps (-1 as size_t); everything read
// from a file or a request goes through this instead. Throws std::out_of_range naming `what`.
template <class T>
requires std::is_arithmetic_v<T> &&(!std::same_as<T, bool>)T
    checked_number(const nlohmann::json& v, const std::string& what) {
  if constexpr (std::is_integral_v<T>) {
    if (v.is_number_unsigned()) {
      const auto x = v.get<std::uint64_t>();
      if (std::cmp_less_equal(x, std::numeric_limits<T>::max())) return static_cast<T>(x);
    } else if (v.is_number_integer()) {
      const auto x = v.get<std::int64_t>();
      if (std::in_range<T>(x)) return static_cast<T>(x);
    }
    throw std::out_of_range(what + " must be an integer in [" +
                            std::to_string(std::numeric_limits<T>::min()) + ", " +
                            std::to_string(std::numeric_limits<T>::max()) + "]");
  } else {
    if (v.is_number()) {
      const double x = v.get<double>();
      if (std::isfinite(x) && std::abs(x) <= static_cast<double>(std::numeric_limits<T>::max())) {
        return static_cast<T>(x);
      }
    }
    throw std::out_of_range(what + " must be a finite number");
  }
}

}  // namespace proden::protocol
