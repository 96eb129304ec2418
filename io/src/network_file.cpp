#include "proden/io/network_file.hpp"

#include <fstream>
#include <iterator>
#include <vector>

#include "proden/network/builtin.hpp"

namespace proden::io {

std::vector<unsigned char> read_weights_file(const std::string& path) {
  std::ifstream f(path, std::ios::binary);
  if (!f) throw network::WeightsError(path + ": cannot be opened");
  return {std::istreambuf_iterator<char>(f), std::istreambuf_iterator<char>()};
}

std::shared_ptr<const network::PdNet> load_network(const std::string& path) {
  if (path.empty()) return network::builtin_network();
  return std::make_shared<const network::PdNet>(
      network::parse_weights(read_weights_file(path), path), path);
}

}  // namespace proden::io
