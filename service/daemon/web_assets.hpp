// WebAssets: the dashboard's static files (web/, built by Vite and packed by
// web/scripts/pack-assets.mjs), embedded in the binary at build time, served from / with their
// MIME types, ETags, caching (hashed assets immutable, the page revalidated) and gzip
// (docs/dashboard.md).
//
// Pack format: the line "PRDNWEB1 <n>\n", n bytes of JSON {"files": [{"path", "type", "etag",
// "immutable", "offset", "size", "gzip_offset", "gzip_size"}]}, then the file bytes (offsets
// count from the end of the JSON; gzip_size 0 = no gzip copy).
#pragma once

#include <cstdint>
#include <map>
#include <optional>
#include <span>
#include <string>

#include "daemon/http_server.hpp"

namespace proden::daemon {

class WebAssets {
 public:
  struct Asset {
    std::string content_type, etag;
    bool immutable = false;
    std::span<const std::uint8_t> identity, gzip;  // gzip empty: none
  };
  // Parses a pack (throws std::runtime_error on a malformed one). The bytes must outlive it.
  explicit WebAssets(std::span<const std::uint8_t> pack);
  // The pack built into this binary (empty when the dashboard was not built: see web/).
  static const WebAssets& builtin();

  const Asset* find(const std::string& path) const;  // "/" is "/index.html"
  bool empty() const { return files_.empty(); }
  std::size_t size() const { return files_.size(); }

  // The response for a GET of `request`'s target if it names an asset: 200 (gzip when the
  // client accepts it), or 304 when If-None-Match matches; nullopt when no asset has that path.
  std::optional<Response> serve(const Request& request) const;

 private:
  std::map<std::string, Asset> files_;
};

// Whether an Accept-Encoding value accepts gzip (a "gzip" or "*" coding without q=0).
bool accepts_gzip(std::string_view accept_encoding);

}  // namespace proden::daemon
