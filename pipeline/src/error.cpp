#include "proden/error.hpp"

namespace proden {

std::string_view to_string(InputErrorKind kind) {
  switch (kind) {
    case InputErrorKind::unreadable:
      return "unreadable";
    case InputErrorKind::missing_channels:
      return "missing_channels";
    case InputErrorKind::size_mismatch:
      return "size_mismatch";
    case InputErrorKind::layout_mismatch:
      return "layout_mismatch";
    case InputErrorKind::duplicate:
      return "duplicate";
    case InputErrorKind::invalid_value:
      return "invalid_value";
    case InputErrorKind::unsupported_format:
      return "unsupported_format";
    case InputErrorKind::too_large:
      return "too_large";
    case InputErrorKind::path_escape:
      return "path_escape";
  }
  return "unknown";
}

InputError::InputError(InputErrorKind kind, std::string subject, const std::string& reason)
    : std::runtime_error(subject + ": " + reason),
      kind_(kind),
      subject_(std::move(subject)),
      reason_(reason) {}

}  // namespace proden
