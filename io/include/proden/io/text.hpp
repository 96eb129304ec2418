// Text that crossed in from outside (file headers, channel names, library error messages,
// request bytes) made safe to log, print and put in JSON: valid UTF-8, no control characters.
#pragma once

#include <cstddef>
#include <string>
#include <string_view>

namespace proden::io {

// True when `s` is well-formed UTF-8 (RFC 3629: no overlongs, no surrogates, <= U+10FFFF).
bool is_valid_utf8(std::string_view s);

// Offset of the first byte that is not part of well-formed UTF-8, or npos.
std::size_t invalid_utf8_offset(std::string_view s);

// `s` with every byte that is not part of well-formed UTF-8, and every C0 control character and
// DEL, written as the four characters "\xNN". Valid text passes through unchanged, so the result
// is always valid UTF-8 and prints as one line.
std::string printable(std::string_view s);

}  // namespace proden::io
