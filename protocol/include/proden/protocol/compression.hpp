// The OpenEXR compressions a published frame may use (job `output.compression`, `proden denoise
// --compression`): the lossless ones, since clients compute errors from the values.
#pragma once

#include <array>
#include <string>
#include <string_view>

namespace proden::protocol {

// PIZ by default: a 1080p frame with every layer writes 2.5x faster than with ZIP and is 9 %
// smaller (bench/RESULTS.md, "Publishing a frame").
inline constexpr std::array<std::string_view, 5> kFrameCompressions = {"piz", "zip", "zips", "rle",
                                                                       "none"};
inline constexpr std::string_view kDefaultFrameCompression = "piz";

bool is_frame_compression(std::string_view name);
std::string frame_compressions();  // "piz, zip, zips, rle, none", for messages

}  // namespace proden::protocol
