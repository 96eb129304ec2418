#include "proden/io/network_file.hpp"

#include <fstream>
#include <iterator>
#include <vector>

#include "proden/network/builtin.hpp"

namespace proden::io {

std::shared_ptr<const network::PdNet> load_network(const std::string& path) {
  if (path.empty()) return network::builtin_network();
  std::ifstream f(path, std::ios::binary);
  if (!f) throw network::WeightsError(path + ": cannot be opened");
  const std::vector<unsigned char> bytes((std::istreambuf_iterator<char>(f)),
                                         std::istreambuf_iterator<char>());
  return std::make_shared<const network::PdNet>(network::parse_weights(bytes, path), path);
}

}  // namespace proden::io
