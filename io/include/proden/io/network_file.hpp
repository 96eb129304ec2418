// Loading the learned mixer's weights from a file (the pipeline itself parses bytes only).
#pragma once

#include <memory>
#include <string>
#include <vector>

#include "proden/network/pdnet.hpp"

namespace proden::io {

// The bytes of the `.pdnw` file at `path`, for PipelineOptions::weights. Throws
// network::WeightsError naming the file when it cannot be opened.
std::vector<unsigned char> read_weights_file(const std::string& path);

// The network in the `.pdnw` file at `path`, or the built-in one when `path` is empty. Throws
// network::WeightsError naming the file (and the field at fault) when it cannot be used.
std::shared_ptr<const network::PdNet> load_network(const std::string& path);

}  // namespace proden::io
