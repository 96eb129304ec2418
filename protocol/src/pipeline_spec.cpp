#include "proden/protocol/pipeline_spec.hpp"

#include <algorithm>

namespace proden::protocol {

using nlohmann::json;

namespace {

constexpr std::string_view kAuto = "auto";

std::string mixer_name(MixerKind k) {
  return k == MixerKind::network ? "network" : "closed-form";
}

std::string joined(const std::vector<std::string>& v) {
  std::string s;
  for (const auto& x : v) s += (s.empty() ? "" : ", ") + x;
  return s;
}

std::vector<PipelineOptionInfo> build_table() {
  std::vector<std::string> denoiser_names = {std::string(kAuto)};
  std::string denoiser_help = "Denoiser: auto (= " + std::string(kDefaultDenoiser) + ")";
  for (const auto& e : denoisers()) {
    denoiser_names.emplace_back(e.name);
    denoiser_help += ", " + std::string(e.name) + " (" + std::string(e.summary) + ")";
  }
  denoiser_names.emplace_back(kNoDenoiser);
  denoiser_help += ", none (publish the accumulated render)";

  using K = OptionKind;
  using O = PipelineOptions;
  std::vector<PipelineOptionInfo> t = {
      {PipelineOption::denoiser, "--denoiser", K::choice, denoiser_names, 0, 0, true, denoiser_help,
       [](O& o, const json& v) {
         const auto s = v.get<std::string>();
         o.denoiser = s == kAuto ? std::string(kDefaultDenoiser) : s;
       },
       [](const O& o) { return json(o.denoiser); }},
      {PipelineOption::mixer,
       "--mixer",
       K::choice,
       {"auto", "network", "closed-form", "stein", "inverse-error"},
       0,
       0,
       true,
       "Mixing weights: auto (= " + mixer_name(kDefaultMixerKind) +
           "), network (the learned PDNet), closed-form (rule from --closed-form-rule), or a "
           "closed-form rule by name: stein, inverse-error",
       [](O& o, const json& v) {
         const auto s = v.get<std::string>();
         o.mixer = s == kAuto       ? kDefaultMixerKind
                   : s == "network" ? MixerKind::network
                                    : MixerKind::closed_form;
         // `stein` and `inverse-error` name the closed-form mixer with that rule.
         if (s == "stein") o.closed_form.rule = ClosedFormRule::stein;
         if (s == "inverse-error") o.closed_form.rule = ClosedFormRule::inverse_error;
       },
       [](const O& o) { return json(mixer_name(o.mixer)); }},
      {PipelineOption::closed_form_rule,
       "--closed-form-rule",
       K::choice,
       {"stein", "inverse-error"},
       0,
       0,
       true,
       "Closed-form mixer rule: stein (MSE-optimal, accounts for y depending on x) or "
       "inverse-error",
       [](O& o, const json& v) {
         o.closed_form.rule = v.get<std::string>() == "stein" ? ClosedFormRule::stein
                                                              : ClosedFormRule::inverse_error;
       },
       [](const O& o) {
         return json(o.closed_form.rule == ClosedFormRule::stein ? "stein" : "inverse-error");
       }},
      {PipelineOption::mixer_radius,
       "--mixer-radius",
       K::integer,
       {},
       0,
       16,
       true,
       "Closed-form mixer: window radius of its smoothed estimates",
       [](O& o, const json& v) { o.closed_form.radius = v.get<int>(); },
       [](const O& o) { return json(o.closed_form.radius); }},
      {PipelineOption::weights,
       "--weights",
       K::text,
       {},
       0,
       0,
       false,
       "Network weights file (.pdnw) instead of the built-in ones (mixer network)",
       nullptr,
       nullptr},
      {PipelineOption::divergence,
       "--divergence",
       K::choice,
       {"auto", "analytic", "mc"},
       0,
       0,
       true,
       "SURE divergence: auto (analytic when the denoiser offers it), analytic, mc",
       [](O& o, const json& v) {
         const auto s = v.get<std::string>();
         o.divergence = s == "analytic" ? DivergenceMethod::analytic
                        : s == "mc"     ? DivergenceMethod::monte_carlo
                                        : DivergenceMethod::automatic;
       },
       [](const O& o) {
         return json(o.divergence == DivergenceMethod::analytic      ? "analytic"
                     : o.divergence == DivergenceMethod::monte_carlo ? "mc"
                                                                     : "auto");
       }},
      {PipelineOption::probes,
       "--probes",
       K::integer,
       {},
       1,
       64,
       true,
       "Monte-Carlo probes for divergence mc",
       [](O& o, const json& v) { o.probes.count = v.get<int>(); },
       [](const O& o) { return json(o.probes.count); }},
      {PipelineOption::t_test,
       "--no-ttest",
       K::boolean,
       {},
       0,
       0,
       true,
       "Skip the t-statistic rescale of alpha",
       [](O& o, const json& v) { o.t_test = v.get<bool>(); },
       [](const O& o) { return json(o.t_test); }},
      {PipelineOption::ttest_dof,
       "--no-ttest-dof",
       K::boolean,
       {},
       0,
       0,
       true,
       "The authors' fixed t-test threshold (no degrees-of-freedom correction)",
       [](O& o, const json& v) { o.ttest.dof_correction = v.get<bool>(); },
       [](const O& o) { return json(o.ttest.dof_correction); }},
      {PipelineOption::features,
       "--no-features",
       K::boolean,
       {},
       0,
       0,
       true,
       "Ignore albedo/normal/depth even if the passes carry them",
       [](O& o, const json& v) { o.features = v.get<bool>(); },
       [](const O& o) { return json(o.features); }},
      {PipelineOption::tile,
       "--tile",
       K::integer,
       {},
       8,
       4096,
       true,
       "Tile size in pixels",
       [](O& o, const json& v) { o.tile = v.get<int>(); },
       [](const O& o) { return json(o.tile); }},
      {PipelineOption::search_radius,
       "--search-radius",
       K::integer,
       {},
       0,
       32,
       true,
       "NL-means search radius",
       [](O& o, const json& v) { o.nlmeans.search_radius = v.get<int>(); },
       [](const O& o) { return json(o.nlmeans.search_radius); }},
      {PipelineOption::patch_radius,
       "--patch-radius",
       K::integer,
       {},
       0,
       16,
       true,
       "NL-means patch radius",
       [](O& o, const json& v) { o.nlmeans.patch_radius = v.get<int>(); },
       [](const O& o) { return json(o.nlmeans.patch_radius); }},
  };
  // Each help ends with the library default, read back through the same accessor.
  const PipelineOptions defaults;
  for (auto& info : t) {
    if (info.kind == K::integer || info.kind == K::choice) {
      const json d = info.read(defaults);
      info.help += " (default: " + (d.is_string() ? d.get<std::string>() : d.dump()) + ")";
    }
  }
  return t;
}

[[noreturn]] void bad(const PipelineOptionInfo& info, const std::string& message) {
  throw PipelineError(info.option, message);
}

void check_value(const PipelineOptionInfo& info, const json& v) {
  switch (info.kind) {
    case OptionKind::choice:
      if (!v.is_string() || std::find(info.choices.begin(), info.choices.end(),
                                      v.get<std::string>()) == info.choices.end()) {
        bad(info, "must be one of " + joined(info.choices));
      }
      return;
    case OptionKind::integer:
      if (!v.is_number_integer() || v.get<long long>() < info.min ||
          v.get<long long>() > info.max) {
        bad(info, "must be an integer in [" + std::to_string(info.min) + ", " +
                      std::to_string(info.max) + "]");
      }
      return;
    case OptionKind::boolean:
      if (!v.is_boolean()) bad(info, "must be true or false");
      return;
    case OptionKind::text:
      bad(info, "is a command-line option (" + info.flag + "), not a job option");
  }
}

}  // namespace

const std::vector<PipelineOptionInfo>& pipeline_option_table() {
  static const std::vector<PipelineOptionInfo> table = build_table();
  return table;
}

const PipelineOptionInfo* find_option(std::string_view key) {
  for (const auto& info : pipeline_option_table()) {
    if (info.key() == key) return &info;
  }
  return nullptr;
}

std::string cli_flag(std::string_view key) {
  const PipelineOptionInfo* info = find_option(key);
  return info ? info->flag : std::string(key);
}

PipelineOptions parse_pipeline_options(const json& given) {
  if (!given.is_object()) throw PipelineError(std::string("pipeline"), "must be an object");
  for (const auto& [key, value] : given.items()) {
    if (!find_option(key)) {
      std::vector<std::string> keys;
      for (const auto& info : pipeline_option_table()) {
        if (info.job) keys.emplace_back(info.key());
      }
      throw PipelineError(key, "unknown option (known: " + joined(keys) + ")");
    }
  }
  PipelineOptions o;
  for (const auto& info : pipeline_option_table()) {  // table order: mixer before its rule
    const auto it = given.find(std::string(info.key()));
    if (it == given.end()) continue;
    check_value(info, *it);
    info.apply(o, *it);
  }
  // mixer stein|inverse-error already names the rule: a different closed_form_rule contradicts it.
  const auto mixer = given.find("mixer"), rule = given.find("closed_form_rule");
  if (mixer != given.end() && rule != given.end() &&
      (*mixer == "stein" || *mixer == "inverse-error") && *mixer != *rule) {
    throw PipelineError(
        PipelineOption::closed_form_rule,
        rule->get<std::string>() + " contradicts mixer " + mixer->get<std::string>());
  }
  return o;
}

json settings_json(const PipelineOptions& options) {
  json j = json::object();
  for (const auto& info : pipeline_option_table()) {
    if (info.job && info.read) j[std::string(info.key())] = info.read(options);
  }
  return j;
}

}  // namespace proden::protocol
