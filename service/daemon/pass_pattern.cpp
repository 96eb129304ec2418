#include "daemon/pass_pattern.hpp"

#include <algorithm>
#include <cstdint>
#include <stdexcept>

namespace proden::daemon {
namespace {

bool is_digit(unsigned char c) {
  return c >= '0' && c <= '9';
}

bool is_pass_char(unsigned char c) {
  return is_digit(c) || (c >= 'A' && c <= 'Z') || (c >= 'a' && c <= 'z') || c == '_' || c == '-';
}

constexpr std::string_view kFrame = "{frame}";
constexpr std::string_view kPass = "{pass}";
constexpr int kMaxFrameDigits = 9;

}  // namespace

std::optional<PassPattern> PassPattern::parse(std::string_view pattern, std::string& why) {
  if (pattern.empty() || pattern.size() > kMaxLength) {
    why = "must be 1-" + std::to_string(kMaxLength) + " bytes";
    return std::nullopt;
  }
  if (pattern.find('\0') != std::string_view::npos) {
    why = "contains NUL";
    return std::nullopt;
  }
  PassPattern out;
  int placeholders = 0;
  bool have_frame = false, have_pass = false;
  std::size_t start = 0;
  while (start <= pattern.size()) {
    const std::size_t end = std::min(pattern.find('/', start), pattern.size());
    const std::string_view seg = pattern.substr(start, end - start);
    if (seg.empty() || seg == "." || seg == "..") {
      why = "empty, '.' or '..' path components are not allowed";
      return std::nullopt;
    }
    if (static_cast<int>(out.segments_.size()) >= kMaxSegments) {
      why = "more than " + std::to_string(kMaxSegments) + " path components";
      return std::nullopt;
    }
    Segment tokens;
    auto literal = [&](char c) {
      if (tokens.empty() || tokens.back().kind != Kind::literal)
        tokens.push_back({Kind::literal, {}});
      tokens.back().text += c;
    };
    for (std::size_t i = 0; i < seg.size();) {
      Token t{Kind::literal, {}, 1};
      std::size_t len = 0;
      if (seg.substr(i).starts_with(kFrame)) {
        t.kind = Kind::frame;
        len = kFrame.size();
      } else if (seg.substr(i).starts_with(kPass)) {
        t.kind = Kind::pass;
        len = kPass.size();
      } else if (seg[i] == '#') {
        while (i + len < seg.size() && seg[i + len] == '#') ++len;
        if (len > static_cast<std::size_t>(kMaxFrameDigits)) {
          why = "a '#' run longer than " + std::to_string(kMaxFrameDigits) + " (frame numbers " +
                "have at most " + std::to_string(kMaxFrameDigits) + " digits)";
          return std::nullopt;
        }
        t.kind = Kind::frame;
        t.min = static_cast<int>(len);
      } else {
        literal(seg[i]);
        ++i;
        continue;
      }
      if (++placeholders > kMaxPlaceholders) {
        why = "more than " + std::to_string(kMaxPlaceholders) + " placeholders";
        return std::nullopt;
      }
      (t.kind == Kind::frame ? have_frame : have_pass) = true;
      tokens.push_back(std::move(t));
      i += len;
    }
    out.segments_.push_back(std::move(tokens));
    start = end + 1;
  }
  if (!have_pass) {
    why = "needs a {pass} placeholder";
    return std::nullopt;
  }
  if (!have_frame) {
    why = "needs a {frame} placeholder (or Blender's #### padding)";
    return std::nullopt;
  }
  return out;
}

PassPattern::PassPattern(std::string_view pattern) {
  std::string why;
  auto p = parse(pattern, why);
  if (!p) throw std::invalid_argument("watch.pattern: " + why);
  *this = std::move(*p);
}

std::optional<PassPattern::Match> PassPattern::match(std::string_view relative,
                                                     std::size_t* steps) const {
  std::size_t work = 0;
  struct Report {  // adds the work done to *steps on every return
    std::size_t* steps;
    const std::size_t& work;
    ~Report() {
      if (steps) *steps += work;
    }
  } report{steps, work};
  if (relative.size() > kMaxPathLength) return std::nullopt;
  std::optional<std::string> frame_text, pass;
  std::size_t start = 0;
  for (std::size_t si = 0; si < segments_.size(); ++si) {
    const std::size_t slash = relative.find('/', start);
    const bool last = si + 1 == segments_.size();
    if (last != (slash == std::string_view::npos)) return std::nullopt;  // depth differs
    const std::string_view s = relative.substr(start, (last ? relative.size() : slash) - start);
    start = slash + 1;
    const Segment& tokens = segments_[si];
    const std::size_t n = s.size(), k = tokens.size();
    // run[p]: how many bytes from p on are in the token's class (per class).
    std::vector<std::uint32_t> digits(n + 1, 0), passc(n + 1, 0);
    work += n + 1;
    for (std::size_t p = n; p-- > 0;) {
      const auto c = static_cast<unsigned char>(s[p]);
      digits[p] = is_digit(c) ? digits[p + 1] + 1 : 0;
      passc[p] = is_pass_char(c) ? passc[p + 1] + 1 : 0;
    }
    // ok[i][p]: tokens i..k-1 match s[p..n). Filled from the back, each row in O(n) with a
    // prefix count of the next row (is any q in [lo, hi] with ok[i+1][q]?).
    std::vector<std::vector<char>> ok(k + 1, std::vector<char>(n + 1, 0));
    work += (k + 1) * (n + 1);
    ok[k][n] = 1;
    std::vector<std::uint32_t> count(n + 2, 0);
    for (std::size_t i = k; i-- > 0;) {
      const Token& t = tokens[i];
      if (t.kind == Kind::literal) {
        work += (n + 1) * t.text.size();
        for (std::size_t p = 0; p + t.text.size() <= n; ++p) {
          ok[i][p] = ok[i + 1][p + t.text.size()] && s.substr(p, t.text.size()) == t.text;
        }
        continue;
      }
      work += 2 * (n + 1);
      for (std::size_t q = 0; q <= n; ++q) count[q + 1] = count[q] + (ok[i + 1][q] ? 1 : 0);
      const auto& run = t.kind == Kind::frame ? digits : passc;
      for (std::size_t p = 0; p <= n; ++p) {
        const std::size_t lo = p + static_cast<std::size_t>(t.min), hi = p + run[p];
        ok[i][p] = lo <= hi && count[hi + 1] > count[lo];
      }
    }
    if (!ok[0][0]) return std::nullopt;
    // Greedy left to right: each placeholder takes the longest span that still lets the rest
    // match.
    std::size_t p = 0;
    for (std::size_t i = 0; i < k; ++i) {
      const Token& t = tokens[i];
      if (t.kind == Kind::literal) {
        p += t.text.size();
        continue;
      }
      const auto& run = t.kind == Kind::frame ? digits : passc;
      std::size_t q = p + run[p];
      while (!ok[i + 1][q]) {  // ok[i][p] guarantees one in [p + min, p + run[p]]
        --q;
        ++work;
      }
      work += q - p + 1;  // the value copied
      std::string value(s.substr(p, q - p));
      auto& slot = t.kind == Kind::frame ? frame_text : pass;
      if (t.kind == Kind::frame && slot) {
        // Same number, however padded: "0007" and "7" agree.
        const auto strip = [](std::string_view v) {
          const auto nz = v.find_first_not_of('0');
          return nz == std::string_view::npos ? std::string_view("0") : v.substr(nz);
        };
        if (strip(*slot) != strip(value)) return std::nullopt;
      } else if (slot && *slot != value) {
        return std::nullopt;
      }
      slot = std::move(value);
      p = q;
    }
  }
  const auto nz = frame_text->find_first_not_of('0');
  const std::string digits = nz == std::string::npos ? "0" : frame_text->substr(nz);
  if (digits.size() > static_cast<std::size_t>(kMaxFrameDigits)) return std::nullopt;
  return Match{std::stol(digits), *pass};
}

}  // namespace proden::daemon
