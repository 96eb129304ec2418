#include "daemon/web_assets.hpp"

#include <algorithm>
#include <cctype>
#include <stdexcept>

#include <nlohmann/json.hpp>

extern const unsigned char proden_dashboard_pack[];
extern const std::size_t proden_dashboard_pack_size;

namespace proden::daemon {

namespace {

std::string_view trim(std::string_view s) {
  while (!s.empty() && std::isspace(static_cast<unsigned char>(s.front()))) s.remove_prefix(1);
  while (!s.empty() && std::isspace(static_cast<unsigned char>(s.back()))) s.remove_suffix(1);
  return s;
}

std::string lower(std::string_view s) {
  std::string out(s);
  std::transform(out.begin(), out.end(), out.begin(),
                 [](unsigned char c) { return static_cast<char>(std::tolower(c)); });
  return out;
}

// RFC 9110 13.1.2: a list of entity tags, or "*"; weak tags compare weakly.
bool etag_matches(std::string_view if_none_match, std::string_view etag) {
  if (trim(if_none_match) == "*") return true;
  std::size_t start = 0;
  while (start <= if_none_match.size()) {
    auto end = if_none_match.find(',', start);
    if (end == std::string_view::npos) end = if_none_match.size();
    auto tag = trim(if_none_match.substr(start, end - start));
    if (tag.substr(0, 2) == "W/") tag.remove_prefix(2);
    if (tag == etag) return true;
    start = end + 1;
  }
  return false;
}

}  // namespace

bool accepts_gzip(std::string_view value) {
  std::size_t start = 0;
  while (start <= value.size()) {
    auto end = value.find(',', start);
    if (end == std::string_view::npos) end = value.size();
    const std::string item = lower(trim(value.substr(start, end - start)));
    const auto semi = item.find(';');
    const std::string coding(trim(std::string_view(item).substr(0, semi)));
    if (coding == "gzip" || coding == "x-gzip" || coding == "*") {
      bool zero = false;
      if (semi != std::string::npos) {
        std::string params = item.substr(semi + 1);
        params.erase(std::remove_if(params.begin(), params.end(), ::isspace), params.end());
        zero =
            params.rfind("q=0", 0) == 0 && params.find_first_not_of("0.", 2) == std::string::npos;
      }
      if (!zero) return true;
    }
    start = end + 1;
  }
  return false;
}

WebAssets::WebAssets(std::span<const std::uint8_t> pack) {
  const std::string_view text(reinterpret_cast<const char*>(pack.data()), pack.size());
  const auto nl = text.find('\n');
  if (text.substr(0, 9) != "PRDNWEB1 " || nl == std::string_view::npos) {
    throw std::runtime_error("dashboard pack: bad magic");
  }
  std::size_t n = 0;
  try {
    n = std::stoul(std::string(text.substr(9, nl - 9)));
  } catch (const std::exception&) {
    throw std::runtime_error("dashboard pack: bad header");
  }
  if (n > pack.size() - nl - 1) throw std::runtime_error("dashboard pack: truncated manifest");
  const auto manifest = nlohmann::json::parse(text.substr(nl + 1, n));
  const auto data = pack.subspan(nl + 1 + n);
  const auto slice = [&](std::uint64_t off, std::uint64_t size) {
    if (off > data.size() || size > data.size() - off) {
      throw std::runtime_error("dashboard pack: a file lies outside the pack");
    }
    return data.subspan(off, size);
  };
  for (const auto& f : manifest.at("files")) {
    Asset a;
    a.content_type = f.at("type").get<std::string>();
    a.etag = f.at("etag").get<std::string>();
    a.immutable = f.at("immutable").get<bool>();
    a.identity = slice(f.at("offset").get<std::uint64_t>(), f.at("size").get<std::uint64_t>());
    if (f.at("gzip_size").get<std::uint64_t>() > 0) {
      a.gzip =
          slice(f.at("gzip_offset").get<std::uint64_t>(), f.at("gzip_size").get<std::uint64_t>());
    }
    files_.emplace(f.at("path").get<std::string>(), a);
  }
}

const WebAssets& WebAssets::builtin() {
  static const WebAssets assets(
      std::span<const std::uint8_t>(proden_dashboard_pack, proden_dashboard_pack_size));
  return assets;
}

const WebAssets::Asset* WebAssets::find(const std::string& path) const {
  auto it = files_.find(path == "/" ? "/index.html" : path);
  return it == files_.end() ? nullptr : &it->second;
}

std::optional<Response> WebAssets::serve(const Request& req) const {
  std::string_view target(req.target().data(), req.target().size());
  target = target.substr(0, target.find_first_of("?#"));
  const Asset* a = find(std::string(target));
  if (!a) return std::nullopt;
  Response r{http::status::ok, req.version()};
  r.set(http::field::server, "proden");
  r.set(http::field::etag, a->etag);
  r.set(http::field::cache_control,
        a->immutable ? "public, max-age=31536000, immutable" : "no-cache");
  r.set(http::field::vary, "Accept-Encoding");
  r.set("X-Content-Type-Options", "nosniff");
  r.set("Referrer-Policy", "no-referrer");
  if (a->content_type.rfind("text/html", 0) == 0) {
    // The page talks only to this daemon and loads nothing from elsewhere.
    r.set("Content-Security-Policy",
          "default-src 'self'; img-src 'self' blob: data:; style-src 'self' 'unsafe-inline'; "
          "connect-src 'self'; object-src 'none'; base-uri 'none'; frame-ancestors 'none'");
  }
  const auto inm = req[http::field::if_none_match];
  if (!inm.empty() && etag_matches(std::string_view(inm.data(), inm.size()), a->etag)) {
    r.result(http::status::not_modified);
    return r;
  }
  r.set(http::field::content_type, a->content_type);
  const auto ae = req[http::field::accept_encoding];
  const auto& bytes = !a->gzip.empty() && accepts_gzip(std::string_view(ae.data(), ae.size()))
                          ? a->gzip
                          : a->identity;
  if (&bytes == &a->gzip) r.set(http::field::content_encoding, "gzip");
  r.body().assign(reinterpret_cast<const char*>(bytes.data()), bytes.size());
  return r;
}

}  // namespace proden::daemon
