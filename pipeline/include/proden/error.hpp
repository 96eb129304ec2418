// Errors about bad input (a pass, a reference, a request): they name the subject (usually a file)
// and a machine-readable kind, so callers can report them and keep their state intact.
#pragma once

#include <stdexcept>
#include <string>
#include <string_view>

namespace proden {

enum class InputErrorKind {
  unreadable,          // cannot open, empty placeholder, truncated or corrupt data
  missing_channels,    // no colour channels the profile recognises
  size_mismatch,       // resolution differs from the frame's
  layout_mismatch,     // carries a different set of features than the frame's earlier passes
  duplicate,           // bit-identical to a pass already accumulated
  invalid_value,       // e.g. spp <= 0
  unsupported_format,  // not a format the renderer profile reads (e.g. a PNG named .exr)
  too_large,           // declares more pixels, channels or bytes than the read limits allow
  path_escape,         // its path leads outside the allowed directories (a symlink, a rename)
};

std::string_view to_string(InputErrorKind kind);

class InputError : public std::runtime_error {
 public:
  InputError(InputErrorKind kind, std::string subject, const std::string& reason);

  InputErrorKind kind() const { return kind_; }
  const std::string& subject() const { return subject_; }
  const std::string& reason() const { return reason_; }

 private:
  InputErrorKind kind_;
  std::string subject_;
  std::string reason_;
};

}  // namespace proden
