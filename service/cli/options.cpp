#include "cli/options.hpp"

#include <string>

namespace proden::cli {

void PipelineFlags::add_to(CLI::App& cmd) {
  for (const auto& info : protocol::pipeline_option_table()) {
    Slot& s = slots_.emplace_back();
    s.info = &info;
    if (CLI::Option* existing = cmd.get_option_no_throw(info.flag)) {
      s.option = existing;
      continue;
    }
    switch (info.kind) {
      case protocol::OptionKind::choice:
        s.option = cmd.add_option(info.flag, s.text, info.help)
                       ->check(CLI::IsMember(info.choices))
                       ->type_name("NAME");
        break;
      case protocol::OptionKind::integer:
        s.option = cmd.add_option(info.flag, s.integer, info.help)
                       ->check(CLI::Range(info.min, info.max))
                       ->type_name("N");
        break;
      case protocol::OptionKind::boolean:
        s.option = cmd.add_flag(info.flag, s.flag, info.help);
        break;
      case protocol::OptionKind::text:
        s.option = cmd.add_option(info.flag, s.text, info.help)->type_name("FILE");
        break;
    }
  }
}

nlohmann::json PipelineFlags::given() const {
  nlohmann::json j = nlohmann::json::object();
  for (const Slot& s : slots_) {
    if (s.option->count() == 0) continue;
    const std::string key(s.info->key());
    switch (s.info->kind) {
      case protocol::OptionKind::choice:
      case protocol::OptionKind::text:
        j[key] = s.option->as<std::string>();
        break;
      case protocol::OptionKind::integer:
        j[key] = s.option->as<int>();
        break;
      case protocol::OptionKind::boolean:
        j[key] = false;  // the flag turns the option off
        break;
    }
  }
  return j;
}

}  // namespace proden::cli
