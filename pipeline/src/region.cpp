#include "proden/region.hpp"

#include <stdexcept>

namespace proden {

std::string Rect::to_string() const {
  return "[" + std::to_string(x0) + "," + std::to_string(x1) + ")x[" + std::to_string(y0) + "," +
         std::to_string(y1) + ")";
}

View view_of(const Image& image) {
  if (image.empty()) return {};
  return {image.data().data(), Rect{0, 0, image.width(), image.height()}, image.channels()};
}

void store(const Buffer& src, const Rect& region, Image& dst) {
  if (!src.rect().contains(region) || !Rect{0, 0, dst.width(), dst.height()}.contains(region) ||
      src.channels() != dst.channels()) {
    throw std::invalid_argument("store: region " + region.to_string() + " not inside buffer " +
                                src.rect().to_string() + " and " + dst.to_string());
  }
  for (int c = 0; c < src.channels(); ++c) {
    for (int y = region.y0; y < region.y1; ++y) {
      for (int x = region.x0; x < region.x1; ++x) dst.at(x, y, c) = src.at(x, y, c);
    }
  }
}

}  // namespace proden
