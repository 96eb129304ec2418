#include "proden/io/profile.hpp"

#include <algorithm>

namespace proden::io {
namespace {

bool has(std::span<const std::string> channels, std::string_view name) {
  return std::find(channels.begin(), channels.end(), name) != channels.end();
}

using Alternatives = std::vector<std::vector<std::string>>;

// {prefix+"R", prefix+"G", prefix+"B"} for each suffix set given.
Alternatives names(const std::string& prefix, std::initializer_list<std::string_view> suffix_sets) {
  Alternatives out;
  for (std::string_view set : suffix_sets) {
    std::vector<std::string> chans;
    for (char c : set) chans.push_back(prefix + c);
    out.push_back(std::move(chans));
  }
  return out;
}

// Blender names its view layers freely: every "<layer>.Combined.R", sorted.
std::vector<std::string> cycles_layers(std::span<const std::string> channels) {
  constexpr std::string_view suffix = ".Combined.R";
  std::vector<std::string> out;
  for (const auto& c : channels) {
    if (c.size() > suffix.size() && c.ends_with(suffix)) {
      out.push_back(c.substr(0, c.size() - suffix.size()));
    }
  }
  std::sort(out.begin(), out.end());
  out.erase(std::unique(out.begin(), out.end()), out.end());
  return out;
}

// The view layers named by "cycles.<layer>.samples" header attributes (single-layer files).
std::vector<std::string> cycles_sample_layers(std::span<const std::string> attribute_names) {
  constexpr std::string_view prefix = "cycles.", suffix = ".samples";
  std::vector<std::string> out;
  for (const auto& a : attribute_names) {
    if (a.size() > prefix.size() + suffix.size() && a.starts_with(prefix) && a.ends_with(suffix)) {
      out.push_back(a.substr(prefix.size(), a.size() - prefix.size() - suffix.size()));
    }
  }
  std::sort(out.begin(), out.end());
  out.erase(std::unique(out.begin(), out.end()), out.end());
  return out;
}

std::string pick_layer(const std::vector<std::string>& layers, std::string_view wanted) {
  if (!wanted.empty()) return std::string(wanted);
  return layers.empty() ? std::string("ViewLayer") : layers.front();
}

ChannelMap cycles_map(const std::string& layer, bool single) {
  ChannelMap m;
  m.renderer = Renderer::cycles;
  m.layer = layer;
  m.single_layer = single;
  m.spp_attribute = "cycles." + layer + ".samples";
  m.render_time_attribute = "cycles." + layer + ".render_time";
  if (single) {  // Blender's OPEN_EXR: the combined pass only, as R,G,B,A
    m.colour = names("", {"RGB"});
    return m;
  }
  const std::string p = layer + ".";
  m.colour = names(p + "Combined.", {"RGB"});
  m.albedo = names(p + "Denoising Albedo.", {"RGB"});
  m.normal = names(p + "Denoising Normal.", {"XYZ"});
  m.depth = names(p + "Denoising Depth.", {"Z"});
  return m;
}

ChannelMap generic_map(Renderer r) {
  ChannelMap m;
  m.renderer = r;
  m.colour = names("", {"RGB"});
  m.albedo = names("Albedo.", {"RGB"});
  m.normal = names("Normal.", {"XYZ", "RGB"});
  m.depth = {{"Depth.Z"}, {"Depth.Y"}, {"Z"}};
  m.variance = names("Variance.", {"RGB"});
  return m;
}

bool has_colour(const ChannelMap& m, std::span<const std::string> channels) {
  return std::any_of(m.colour.begin(), m.colour.end(), [&](const auto& set) {
    return std::all_of(set.begin(), set.end(), [&](const auto& n) { return has(channels, n); });
  });
}

}  // namespace

std::string_view to_string(Renderer r) {
  switch (r) {
    case Renderer::automatic:
      return "auto";
    case Renderer::cycles:
      return "cycles";
    case Renderer::povray:
      return "povray";
    case Renderer::generic:
      return "generic";
  }
  return "?";
}

std::span<const FileFormat> accepted_formats(Renderer r) {
  static constexpr FileFormat exr_only[] = {FileFormat::exr};
  static constexpr FileFormat exr_or_hdr[] = {FileFormat::exr, FileFormat::radiance};
  if (r == Renderer::cycles) return exr_only;
  return exr_or_hdr;
}

bool accepts(Renderer r, FileFormat f) {
  const auto list = accepted_formats(r);
  return std::find(list.begin(), list.end(), f) != list.end();
}

std::optional<Renderer> parse_renderer(std::string_view s) {
  for (Renderer r : {Renderer::automatic, Renderer::cycles, Renderer::povray, Renderer::generic}) {
    if (s == to_string(r)) return r;
  }
  return std::nullopt;
}

std::optional<ChannelMap> detect_profile(std::span<const std::string> channels,
                                         std::span<const std::string> attribute_values,
                                         Renderer forced,
                                         std::span<const std::string> attribute_names,
                                         std::string_view view_layer) {
  std::optional<ChannelMap> m;
  const auto layers = cycles_layers(channels);
  const auto sample_layers = cycles_sample_layers(attribute_names);
  const bool pov = std::any_of(attribute_values.begin(), attribute_values.end(),
                               [](const std::string& v) { return v.find("POV-Ray") != v.npos; });
  const bool single = layers.empty() && !sample_layers.empty();
  auto cycles = [&] {
    ChannelMap c = single ? cycles_map(pick_layer(sample_layers, view_layer), true)
                          : cycles_map(pick_layer(layers, view_layer), false);
    c.layers = single ? sample_layers : layers;
    return c;
  };
  switch (forced) {
    case Renderer::cycles:
      m = cycles();
      break;
    case Renderer::povray:
    case Renderer::generic:
      m = generic_map(forced);
      break;
    case Renderer::automatic:
      if (!layers.empty() || (single && !pov)) {
        m = cycles();
      } else {
        m = generic_map(pov ? Renderer::povray : Renderer::generic);
      }
      break;
  }
  if (!has_colour(*m, channels)) return std::nullopt;
  return m;
}

std::vector<AovSource> aov_sources(const ChannelMap& map, std::span<const std::string> channels) {
  std::vector<std::string> used;
  for (const auto* sets : {&map.colour, &map.albedo, &map.normal, &map.depth, &map.variance}) {
    for (const auto& set : *sets) used.insert(used.end(), set.begin(), set.end());
  }
  std::vector<AovSource> out;
  const bool layered = map.renderer == Renderer::cycles && !map.single_layer;
  const std::string prefix = map.layer + ".";
  for (const auto& c : channels) {
    if (std::find(used.begin(), used.end(), c) != used.end()) continue;
    std::string name = c;
    if (layered) {
      if (!c.starts_with(prefix)) continue;  // another view layer's
      name = c.substr(prefix.size());
      if (name.starts_with("Denoising ")) continue;  // the denoiser's features
      if (name == "Combined.A") name = "A";
      if (name.starts_with("Combined.")) continue;
    }
    if (name.empty()) continue;
    out.push_back({c, name});
  }
  return out;
}

std::vector<std::pair<std::string, std::string>> aov_attributes(
    const ChannelMap& map, std::span<const std::pair<std::string, std::string>> attributes,
    std::span<const AovSource> sources) {
  const bool layered = map.renderer == Renderer::cycles && !map.single_layer;
  const std::string prefix = map.layer + ".";
  // Cryptomatte ids whose layer is written: "cryptomatte/<id>/name" = [<view layer>.]<layer>.
  std::vector<std::pair<std::string, std::string>> ids;  // id prefix -> name as written
  for (const auto& [k, v] : attributes) {
    if (!k.starts_with("cryptomatte/") || !k.ends_with("/name")) continue;
    std::string name = v;
    if (layered) {
      if (!name.starts_with(prefix)) continue;
      name = name.substr(prefix.size());
    }
    const bool written = std::any_of(sources.begin(), sources.end(), [&](const AovSource& s) {
      return s.name.starts_with(name) && s.name.size() > name.size();
    });
    if (written) ids.emplace_back(k.substr(0, k.size() - 4), name);
  }
  std::vector<std::pair<std::string, std::string>> out;
  for (const auto& [k, v] : attributes) {
    for (const auto& [id, name] : ids) {
      if (k.starts_with(id)) out.emplace_back(k, k == id + "name" ? name : v);
    }
  }
  return out;
}

}  // namespace proden::io
