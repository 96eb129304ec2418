// The OpenEXR compressions a published frame may use (job `output.compression`, `proden denoise
// --compression`): the lossless ones, since clients compute errors from the values.
#pragma once

#include <array>
#include <string>
#include <string_view>

namespace proden::protocol {

// PIZ: a 1080p frame with every layer writes 2.5x faster than with ZIP and is 9 % smaller
// (bench/RESULTS.md, "Publishing a frame"), but its coder is still ~2.6 CPU-s of a 1080p update,
// where `none` takes 0.3 and writes 26 % more bytes. `auto` (the default) ends as PIZ: the CLI
// writes PIZ; the daemon writes each version uncompressed, so that it is out ~1 s sooner at
// 1080p, and compresses the file in place once it is idle (the same values; docs/api.md,
// `output.compression`).
inline constexpr std::array<std::string_view, 6> kFrameCompressions = {"auto", "piz", "zip",
                                                                       "zips", "rle", "none"};
inline constexpr std::string_view kDefaultFrameCompression = "auto";

bool is_frame_compression(std::string_view name);
std::string frame_compressions();  // "auto, piz, zip, zips, rle, none", for messages
// The OpenEXR compression a frame's file ends with: `name` itself, or PIZ for `auto`. Throws
// std::invalid_argument for an unknown name.
std::string_view resolve_frame_compression(std::string_view name);

}  // namespace proden::protocol
