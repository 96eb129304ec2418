// The trained mixing network built into the binary (training/weights/, docs/mixer_network.md),
// and which mixer proden uses when none is asked for.
#pragma once

#include <memory>
#include <span>
#include <string>

#include "proden/network/pdnet.hpp"

namespace proden::network {

// The default mixer, chosen on the validation scenes (docs/mixer_network.md has the table):
// "network" or "closed-form". The trained network wins on SMAPE but loses on mean relMSE (it
// keeps some fireflies of x at 4-8 spp), so the closed form stays the default.
inline constexpr const char* kDefaultMixer = "closed-form";

// Bytes of the built-in weights file and its name (e.g. "pdnet.pdnw").
std::span<const unsigned char> builtin_weights();
std::string builtin_weights_name();

// The built-in network, parsed once (thread-safe); throws WeightsError if the embedded file is
// unusable (a build error, since the build embeds a checked file).
std::shared_ptr<const PdNet> builtin_network();

}  // namespace proden::network
