// The OpenEXR compressions a published frame may use (job `output.compression`, `proden denoise
// --compression`): the lossless ones, since clients compute errors from the values.
#pragma once

#include <array>
#include <string>
#include <string_view>

namespace proden::protocol {

// PIZ: a 1080p frame with every layer writes 2.5x faster than with ZIP and is 9 % smaller
// (bench/RESULTS.md, "Publishing a frame"), but its coder is still ~2.6 CPU-s of a 1080p update,
// where `none` takes 0.3 and writes 26 % more bytes. `auto` (the default) is PIZ, except when work
// waits for the daemon's workers (Scheduler::backlog): then the CPU is what the farm is short of,
// and the version is written uncompressed (the same values; docs/api.md, `output.compression`).
inline constexpr std::array<std::string_view, 6> kFrameCompressions = {"auto", "piz", "zip",
                                                                       "zips", "rle", "none"};
inline constexpr std::string_view kDefaultFrameCompression = "auto";

bool is_frame_compression(std::string_view name);
std::string frame_compressions();  // "auto, piz, zip, zips, rle, none", for messages
// The OpenEXR compression a frame is written with: `name` itself, or for `auto` PIZ, and `none`
// when `backlog` (work waits for the daemon's workers). Throws std::invalid_argument for an unknown
// name.
std::string_view resolve_frame_compression(std::string_view name, bool backlog = false);

}  // namespace proden::protocol
