// The Denoiser interface's defaults.
#include "proden/denoise/denoiser.hpp"

#include <stdexcept>

namespace proden {

void Denoiser::denoise_with_error(const DenoiseInputs&, const Rect&, Buffer&, Buffer&) const {
  throw std::logic_error("denoiser " + name() + " offers no error estimate");
}

}  // namespace proden
