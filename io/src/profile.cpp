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

// Blender names its view layer freely: find "<layer>.Combined.R".
std::optional<std::string> cycles_layer(std::span<const std::string> channels) {
  constexpr std::string_view suffix = ".Combined.R";
  for (const auto& c : channels) {
    if (c.size() > suffix.size() && c.ends_with(suffix)) {
      return c.substr(0, c.size() - suffix.size());
    }
  }
  return std::nullopt;
}

ChannelMap cycles_map(const std::string& layer) {
  ChannelMap m;
  m.renderer = Renderer::cycles;
  m.layer = layer;
  const std::string p = layer + ".";
  m.colour = names(p + "Combined.", {"RGB"});
  m.albedo = names(p + "Denoising Albedo.", {"RGB"});
  m.normal = names(p + "Denoising Normal.", {"XYZ"});
  m.depth = names(p + "Denoising Depth.", {"Z"});
  m.spp_attribute = "cycles." + layer + ".samples";
  m.render_time_attribute = "cycles." + layer + ".render_time";
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
                                         Renderer forced) {
  std::optional<ChannelMap> m;
  const auto layer = cycles_layer(channels);
  const bool pov = std::any_of(attribute_values.begin(), attribute_values.end(),
                               [](const std::string& v) { return v.find("POV-Ray") != v.npos; });
  switch (forced) {
    case Renderer::cycles:
      m = cycles_map(layer.value_or("ViewLayer"));
      break;
    case Renderer::povray:
    case Renderer::generic:
      m = generic_map(forced);
      break;
    case Renderer::automatic:
      if (layer) {
        m = cycles_map(*layer);
      } else {
        m = generic_map(pov ? Renderer::povray : Renderer::generic);
      }
      break;
  }
  if (!has_colour(*m, channels)) return std::nullopt;
  return m;
}

}  // namespace proden::io
