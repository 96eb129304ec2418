#include "proden/io/pass_reader.hpp"

#include <OpenImageIO/imageio.h>

#include <charconv>
#include <cstdio>
#include <filesystem>
#include <map>
#include <sstream>
#include <system_error>

#include "proden/error.hpp"

namespace proden::io {
namespace {

namespace fs = std::filesystem;

[[noreturn]] void fail(InputErrorKind kind, const std::string& path, const std::string& reason) {
  throw InputError(kind, path, reason);
}

struct ChannelRef {
  int subimage = 0;
  int index = 0;
};

struct Header {
  std::string format;
  int width = 0, height = 0, subimages = 0;
  std::vector<std::string> channels;
  std::map<std::string, ChannelRef> where;
  std::vector<std::string> attribute_values;
  std::map<std::string, std::string> attributes;  // name -> value as string
  std::vector<OIIO::TypeDesc> channel_types;
};

std::string oiio_error(const OIIO::ImageInput* in) {
  std::string e = in ? in->geterror() : OIIO::geterror();
  if (e.empty()) e = OIIO::geterror();
  while (!e.empty() && (e.back() == '\n' || e.back() == ' ')) e.pop_back();
  return e.empty() ? "unknown read error" : e;
}

std::unique_ptr<OIIO::ImageInput> open_checked(const std::string& path) {
  std::error_code ec;
  const auto status = fs::status(path, ec);
  if (ec || !fs::exists(status)) fail(InputErrorKind::unreadable, path, "no such file");
  if (!fs::is_regular_file(status)) fail(InputErrorKind::unreadable, path, "not a regular file");
  const auto size = fs::file_size(path, ec);
  if (ec) fail(InputErrorKind::unreadable, path, "cannot stat: " + ec.message());
  if (size == 0) {
    fail(InputErrorKind::unreadable, path,
         "empty file (0 bytes): a render placeholder or a file still being written");
  }
  auto in = OIIO::ImageInput::open(path);
  if (!in) fail(InputErrorKind::unreadable, path, "not a readable image: " + oiio_error(nullptr));
  return in;
}

Header read_header(OIIO::ImageInput& in, const std::string& path) {
  Header h;
  h.format = in.format_name();
  for (int s = 0; in.seek_subimage(s, 0); ++s) {
    const OIIO::ImageSpec& spec = in.spec();
    if (s == 0) {
      h.width = spec.width;
      h.height = spec.height;
      if (spec.x != spec.full_x || spec.y != spec.full_y || spec.width != spec.full_width ||
          spec.height != spec.full_height) {
        fail(InputErrorKind::unreadable, path,
             "data window differs from display window (crop/border renders are not supported)");
      }
      for (const auto& a : spec.extra_attribs) {
        const std::string v = a.get_string(1 << 20);
        h.attribute_values.push_back(v);
        h.attributes[a.name().string()] = v;
      }
    } else if (spec.width != h.width || spec.height != h.height) {
      continue;  // parts of other sizes (previews) are not ours
    }
    if (spec.depth > 1) fail(InputErrorKind::unreadable, path, "volume images are not passes");
    for (int c = 0; c < spec.nchannels; ++c) {
      const std::string& name = spec.channelnames[static_cast<std::size_t>(c)];
      if (h.where.count(name)) continue;
      h.where[name] = {s, c};
      h.channels.push_back(name);
      h.channel_types.push_back(spec.channelformat(c));
    }
    h.subimages = s + 1;
  }
  if (h.width <= 0 || h.height <= 0) fail(InputErrorKind::unreadable, path, "image has no pixels");
  return h;
}

// First alternative whose channels all exist, or empty.
std::vector<std::string> pick(const Header& h, const std::vector<std::vector<std::string>>& alts) {
  for (const auto& set : alts) {
    bool all = true;
    for (const auto& n : set) all = all && h.where.count(n) > 0;
    if (all) return set;
  }
  return {};
}

double parse_number(const std::string& s) {
  double v = 0.0;
  const auto [ptr, ec] = std::from_chars(s.data(), s.data() + s.size(), v);
  if (ec != std::errc() || ptr == s.data()) return -1.0;
  return v;
}

// Blender writes render time as "MM:SS.ss" or "HH:MM:SS.ss".
std::optional<double> parse_duration(const std::string& s) {
  if (s.empty()) return std::nullopt;
  double total = 0.0;
  std::stringstream ss(s);
  std::string part;
  while (std::getline(ss, part, ':')) {
    const double v = parse_number(part);
    if (v < 0.0) return std::nullopt;
    total = total * 60.0 + v;
  }
  return total;
}

struct Resolved {
  ChannelMap map;
  std::vector<std::string> colour, albedo, normal, depth, variance;
  std::vector<AovSource> aovs;
};

Resolved resolve(const Header& h, const std::string& path, const ReadOptions& options,
                 PassInfo& info) {
  std::vector<std::string> attribute_names;
  for (const auto& [k, v] : h.attributes) attribute_names.push_back(k);
  auto map = detect_profile(h.channels, h.attribute_values, options.renderer, attribute_names,
                            options.view_layer);
  if (!options.view_layer.empty()) {  // a chosen Cycles view layer must be there
    const auto any =
        detect_profile(h.channels, h.attribute_values, options.renderer, attribute_names);
    if (any && any->renderer == Renderer::cycles &&
        std::find(any->layers.begin(), any->layers.end(), options.view_layer) ==
            any->layers.end()) {
      std::string have;
      for (const auto& l : any->layers) have += (have.empty() ? "" : ", ") + l;
      fail(InputErrorKind::missing_channels, path,
           "no view layer '" + options.view_layer +
               "' (the file has: " + (have.empty() ? "none" : have) + ")");
    }
  }
  if (!map) {
    std::string found;
    for (const auto& c : h.channels) found += (found.empty() ? "" : ", ") + c;
    fail(InputErrorKind::missing_channels, path,
         "no colour channels (expected R,G,B or <ViewLayer>.Combined.{R,G,B} for profile " +
             std::string(to_string(options.renderer)) + "); found: " + found);
  }
  Resolved r{*map, pick(h, map->colour), {}, {}, {}, {}, aov_sources(*map, h.channels)};
  if (options.features) {
    r.albedo = pick(h, map->albedo);
    r.normal = pick(h, map->normal);
    r.depth = pick(h, map->depth);
  }
  if (options.variance) r.variance = pick(h, map->variance);

  info.path = path;
  info.format = h.format;
  info.renderer = map->renderer;
  info.layer = map->layer;
  info.layers = map->layers;
  info.aovs.clear();
  for (const auto& a : r.aovs) info.aovs.push_back(a.name);
  {
    const std::vector<std::pair<std::string, std::string>> attrs(h.attributes.begin(),
                                                                 h.attributes.end());
    info.aov_attributes = aov_attributes(*map, attrs, r.aovs);
  }
  info.width = h.width;
  info.height = h.height;
  info.subimages = h.subimages;
  info.channels = h.channels;
  {
    const auto it = std::find(h.channels.begin(), h.channels.end(), r.colour[0]);
    info.pixel_type = h.channel_types[static_cast<std::size_t>(it - h.channels.begin())].c_str();
  }
  info.layout = {!r.albedo.empty(), !r.normal.empty(), !r.depth.empty(), !r.variance.empty()};

  info.spp_source = SppSource::assumed;
  info.spp = 1.0;
  if (const auto it = h.attributes.find(map->spp_attribute);
      !map->spp_attribute.empty() && it != h.attributes.end()) {
    const double spp = parse_number(it->second);
    if (!(spp > 0.0)) {
      fail(InputErrorKind::invalid_value, path,
           "header attribute " + map->spp_attribute + " = '" + it->second +
               "' is not a positive sample count");
    }
    info.spp = spp;
    info.spp_source = SppSource::header;
  } else if (options.spp) {
    if (!(*options.spp > 0.0)) {
      fail(InputErrorKind::invalid_value, path, "--spp must be positive");
    }
    info.spp = *options.spp;
    info.spp_source = SppSource::option;
  }
  if (const auto it = h.attributes.find(map->render_time_attribute);
      !map->render_time_attribute.empty() && it != h.attributes.end()) {
    info.render_time = parse_duration(it->second);
  }
  return r;
}

}  // namespace

std::string_view to_string(SppSource s) {
  switch (s) {
    case SppSource::header:
      return "header";
    case SppSource::option:
      return "option";
    case SppSource::assumed:
      return "assumed";
  }
  return "?";
}

std::string PassInfo::to_string() const {
  std::ostringstream o;
  o << path << ": " << io::to_string(renderer) << " " << format << " " << width << "x" << height
    << " " << pixel_type << ", " << layout.to_string() << ", spp " << spp << " ("
    << io::to_string(spp_source) << ")";
  return o.str();
}

PassInfo probe_pass(const std::string& path, const ReadOptions& options) {
  auto in = open_checked(path);
  const Header h = read_header(*in, path);
  PassInfo info;
  resolve(h, path, options, info);
  return info;
}

namespace {

// Reads the named channels (all present in `h`) as one planar image; each subimage is read once.
class ChannelLoader {
 public:
  ChannelLoader(OIIO::ImageInput& in, const Header& h, const std::string& path)
      : in_(in), h_(h), path_(path) {}

  Image load(const std::vector<std::string>& names) {
    if (names.empty()) return Image();
    Image img(h_.width, h_.height, static_cast<int>(names.size()));
    for (std::size_t c = 0; c < names.size(); ++c) {
      const ChannelRef ref = h_.where.at(names[c]);
      const auto& [buf, nch] = part(ref.subimage);
      auto plane = img.plane(static_cast<int>(c));
      for (std::size_t p = 0; p < plane.size(); ++p) {
        plane[p] = buf[p * nch + static_cast<std::size_t>(ref.index)];
      }
    }
    return img;
  }

 private:
  // All channels of a subimage as float (OIIO converts half), read on first use.
  const std::pair<std::vector<float>, std::size_t>& part(int s) {
    if (auto it = parts_.find(s); it != parts_.end()) return it->second;
    if (!in_.seek_subimage(s, 0)) fail(InputErrorKind::unreadable, path_, oiio_error(&in_));
    const int nch = in_.spec().nchannels;
    std::vector<float> buf(static_cast<std::size_t>(h_.width) *
                           static_cast<std::size_t>(h_.height) * static_cast<std::size_t>(nch));
    if (!in_.read_image(s, 0, 0, nch, OIIO::TypeDesc::FLOAT, buf.data())) {
      fail(InputErrorKind::unreadable, path_,
           "truncated or corrupt pixel data: " + oiio_error(&in_));
    }
    return parts_[s] = {std::move(buf), static_cast<std::size_t>(nch)};
  }

  OIIO::ImageInput& in_;
  const Header& h_;
  const std::string& path_;
  std::map<int, std::pair<std::vector<float>, std::size_t>> parts_;
};

}  // namespace

Pass read_pass(const std::string& path, const ReadOptions& options, PassInfo* info_out,
               std::vector<AovChannel>* aovs) {
  auto in = open_checked(path);
  const Header h = read_header(*in, path);
  PassInfo info;
  const Resolved r = resolve(h, path, options, info);
  ChannelLoader loader(*in, h, path);
  Pass pass;
  pass.colour = loader.load(r.colour);
  pass.albedo = loader.load(r.albedo);
  pass.normal = loader.load(r.normal);
  pass.depth = loader.load(r.depth);
  pass.variance = loader.load(r.variance);
  pass.spp = info.spp;
  if (aovs) {
    aovs->clear();
    for (const auto& a : r.aovs) aovs->push_back({a.name, loader.load({a.channel})});
  }
  in->close();
  if (info_out) *info_out = std::move(info);
  return pass;
}

Image read_layer(const std::string& path, const std::string& layer, const ReadOptions& options) {
  if (layer.empty() || layer == "result") return read_rgb(path, options);
  auto in = open_checked(path);
  const Header h = read_header(*in, path);
  const std::vector<std::string> names = {layer + ".R", layer + ".G", layer + ".B"};
  for (const auto& n : names) {
    if (!h.where.count(n)) {
      fail(InputErrorKind::missing_channels, path, "no layer '" + layer + "' (channel " + n + ")");
    }
  }
  return ChannelLoader(*in, h, path).load(names);
}

Image read_rgb(const std::string& path, const ReadOptions& options) {
  ReadOptions o = options;
  o.features = false;
  o.variance = false;
  return read_pass(path, o).colour;
}

}  // namespace proden::io
