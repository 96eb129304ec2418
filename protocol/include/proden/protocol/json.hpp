// JSON forms of proden's reports: what a pass file holds, error metrics, a frame's accumulated
// state. Field names are part of the contract with integrations: extend, never rename.
#pragma once

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

}  // namespace proden::protocol
