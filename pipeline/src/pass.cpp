#include "proden/pass.hpp"

namespace proden {

std::string Layout::to_string() const {
  std::string s = "HDR";
  if (albedo) s += "+ALB";
  if (normal) s += "+NRM";
  if (depth) s += "+DEP";
  if (variance) s += "+VAR";
  return s;
}

}  // namespace proden
