#include "proden/network/builtin.hpp"

#include <cstddef>

extern const unsigned char proden_builtin_pdnw[];
extern const std::size_t proden_builtin_pdnw_size;
extern const char proden_builtin_pdnw_name[];

namespace proden::network {

std::span<const unsigned char> builtin_weights() {
  return {proden_builtin_pdnw, proden_builtin_pdnw_size};
}

std::string builtin_weights_name() {
  return std::string("built-in ") + proden_builtin_pdnw_name;
}

std::shared_ptr<const PdNet> builtin_network() {
  static const std::shared_ptr<const PdNet> net = std::make_shared<const PdNet>(
      parse_weights(builtin_weights(), builtin_weights_name()), builtin_weights_name());
  return net;
}

}  // namespace proden::network
