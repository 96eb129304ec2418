// The readers' one way to reject input (io/image_header.cpp, io/pass_reader.cpp): an InputError
// whose name and reason are printable, since both may quote the file's own bytes.
#pragma once

#include <string>

#include "proden/error.hpp"
#include "proden/io/text.hpp"

namespace proden::io::detail {

[[noreturn]] inline void fail(InputErrorKind kind, const std::string& name,
                              const std::string& reason) {
  throw InputError(kind, printable(name), printable(reason));
}

}  // namespace proden::io::detail
