#include "proden/image.hpp"

#include <stdexcept>

namespace proden {

namespace {
void check_dimensions(int width, int height, int channels) {
  if (width < 0 || height < 0 || channels < 0) {
    throw std::invalid_argument("Image: negative dimension " + std::to_string(width) + "x" +
                                std::to_string(height) + "x" + std::to_string(channels));
  }
}
}  // namespace

Image::Image(int width, int height, int channels, float fill)
    : width_(width), height_(height), channels_(channels) {
  check_dimensions(width, height, channels);
  data_.assign(pixels() * static_cast<std::size_t>(channels), fill);
}

Image::Image(int width, int height, int channels, Uninitialized)
    : width_(width), height_(height), channels_(channels) {
  check_dimensions(width, height, channels);
  data_.resize(pixels() * static_cast<std::size_t>(channels));
}

std::span<float> Image::plane(int c) {
  if (c < 0 || c >= channels_) throw std::out_of_range("Image::plane " + std::to_string(c));
  return std::span<float>(data_).subspan(static_cast<std::size_t>(c) * pixels(), pixels());
}

std::span<const float> Image::plane(int c) const {
  if (c < 0 || c >= channels_) throw std::out_of_range("Image::plane " + std::to_string(c));
  return std::span<const float>(data_).subspan(static_cast<std::size_t>(c) * pixels(), pixels());
}

std::string Image::to_string() const {
  return "Image(" + std::to_string(width_) + "x" + std::to_string(height_) + "x" +
         std::to_string(channels_) + ")";
}

}  // namespace proden
