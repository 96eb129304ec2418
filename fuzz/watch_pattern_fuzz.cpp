// Fuzz target: a job's watch pattern (daemon/pass_pattern.hpp) compiled and matched against file
// names. Input: the pattern, then '\n'-separated relative paths.
//
// Properties (issue 11, class 3):
//  - no crash or UB; a refused pattern's reason is JSON-safe text;
//  - linear time: every match takes at most (path bytes + 2) x (2 x pattern bytes + 64) steps, also
//    for the path repeated out to 4 KiB (PassPattern::kMaxPathLength);
//  - a match is sane: frame in [0, 10^9), pass non-empty of [A-Za-z0-9_-];
//  - for a pattern with one frame placeholder and one {pass}, on short paths, the result equals a
//    backtracking regular expression's (std::regex ECMAScript: greedy groups, left to right), the
//    meaning the grammar documents.
#include <cstdint>
#include <regex>
#include <string>
#include <string_view>

#include "daemon/pass_pattern.hpp"
#include "fuzz_check.hpp"

using proden::daemon::PassPattern;

namespace {

std::size_t budget(std::size_t pattern, std::size_t path) {
  return (path + 2) * (2 * pattern + 64);
}

bool pass_char(char c) {
  return (c >= '0' && c <= '9') || (c >= 'A' && c <= 'Z') || (c >= 'a' && c <= 'z') || c == '_' ||
         c == '-';
}

// The oracle: the pattern as an ECMAScript regex, when it has one frame placeholder ({frame} or a
// run of '#') and one {pass}. Empty when it has others.
std::optional<std::regex> oracle(std::string_view pattern) {
  std::string re;
  int frames = 0, passes = 0;
  for (std::size_t i = 0; i < pattern.size();) {
    const std::string_view rest = pattern.substr(i);
    if (rest.starts_with("{frame}")) {
      re += "([0-9]+)";
      ++frames;
      i += 7;
    } else if (rest.starts_with("{pass}")) {
      re += "([A-Za-z0-9_-]+)";
      ++passes;
      i += 6;
    } else if (pattern[i] == '#') {
      std::size_t n = 0;
      while (i + n < pattern.size() && pattern[i + n] == '#') ++n;
      re += "([0-9]{" + std::to_string(n) + ",})";
      ++frames;
      i += n;
    } else {
      const auto u = static_cast<unsigned char>(pattern[i]);
      static constexpr char kHex[] = "0123456789abcdef";
      re += "\\x";
      re += kHex[u >> 4];
      re += kHex[u & 15];
      ++i;
    }
  }
  if (frames != 1 || passes != 1) return std::nullopt;
  return std::regex(re, std::regex::ECMAScript);
}

}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  const std::string_view in(reinterpret_cast<const char*>(data), size);
  const std::size_t nl = in.find('\n');
  const std::string_view pattern = in.substr(0, nl);
  std::string why;
  const auto p = PassPattern::parse(pattern, why);
  if (!p) {
    proden::fuzz::check_json_safe(why);
    return 0;
  }
  FUZZ_CHECK(pattern.size() <= PassPattern::kMaxLength);
  FUZZ_CHECK(p->depth() >= 0 && p->depth() < PassPattern::kMaxSegments);
  if (nl == std::string_view::npos) return 0;
  const bool small = pattern.size() <= 64;
  const auto re = small ? oracle(pattern) : std::nullopt;
  std::string_view names = in.substr(nl + 1);
  for (bool first = true;; first = false) {
    const std::size_t end = names.find('\n');
    const std::string_view name = names.substr(0, end);
    std::size_t steps = 0;
    const auto m = p->match(name, &steps);
    FUZZ_CHECK(steps <= budget(pattern.size(), name.size()));
    if (m) {
      FUZZ_CHECK(m->frame >= 0 && m->frame <= 999999999);
      FUZZ_CHECK(!m->pass.empty() && m->pass.size() <= name.size());
      for (const char c : m->pass) FUZZ_CHECK(pass_char(c));
    }
    if (re && name.size() <= 48) {
      std::cmatch g;
      bool expect = std::regex_match(name.data(), name.data() + name.size(), g, *re);
      long frame = -1;
      std::string pass;
      if (expect) {
        // Group order follows the pattern: the frame group is the one of digits only.
        const std::string a = g[1].str(), b = g[2].str();
        const bool frame_first =
            pattern.find("{pass}") > std::min(pattern.find("{frame}"), pattern.find('#'));
        const std::string& f = frame_first ? a : b;
        pass = frame_first ? b : a;
        const auto nz = f.find_first_not_of('0');
        const std::string digits = nz == std::string::npos ? "0" : f.substr(nz);
        if (digits.size() > 9) {
          expect = false;
        } else {
          frame = std::stol(digits);
        }
      }
      FUZZ_CHECK(m.has_value() == expect);
      if (m) FUZZ_CHECK(m->frame == frame && m->pass == pass);
    }
    // The first name repeated out to the longest path the matcher takes: still linear.
    if (first && !name.empty()) {
      std::string longest;
      while (longest.size() + name.size() <= PassPattern::kMaxPathLength) longest += name;
      std::size_t long_steps = 0;
      (void)p->match(longest, &long_steps);
      FUZZ_CHECK(long_steps <= budget(pattern.size(), longest.size()));
    }
    if (end == std::string_view::npos) break;
    names = names.substr(end + 1);
  }
  return 0;
}
