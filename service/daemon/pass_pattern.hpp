// A job's watch pattern (`watch.pattern`, docs/api.md) and the matcher that maps a watched file's
// relative path to (frame, pass). It is a grammar of its own, matched in time linear in the path
// for a bounded pattern: no regular-expression engine, no backtracking, so no file name can make
// the watcher spin (issue 11, class 3). Both functions work on plain byte strings (fuzz targets).
#pragma once

#include <cstddef>
#include <optional>
#include <string>
#include <string_view>
#include <vector>

namespace proden::daemon {

class PassPattern {
 public:
  // Grammar: '/'-separated segments of literal bytes and placeholders
  //   {frame}  one or more digits           (the frame number, at most 9 digits)
  //   ###...#  a run of N '#': at least N digits (Blender's padding; N <= 9)
  //   {pass}   one or more of A-Z a-z 0-9 _ -
  // Placeholders never match '/'. A placeholder repeated must match the same value each time.
  static constexpr std::size_t kMaxLength = 512;       // bytes of pattern
  static constexpr int kMaxPlaceholders = 8;           // {frame}, ####, {pass} together
  static constexpr int kMaxSegments = 16;              // directory levels + 1
  static constexpr std::size_t kMaxPathLength = 4096;  // longer relative paths never match

  // The compiled pattern, or nullopt with `why` saying what is wrong (for a 400 invalid_field).
  static std::optional<PassPattern> parse(std::string_view pattern, std::string& why);
  // Throws std::invalid_argument with the reason.
  explicit PassPattern(std::string_view pattern);

  struct Match {
    long frame;
    std::string pass;
  };
  // Whole-path match. Within a segment placeholders take as much as they can, left to right,
  // while the rest still matches (what a greedy regex would pick), in O(tokens x length).
  std::optional<Match> match(std::string_view relative) const { return match(relative, nullptr); }
  // The same, adding to `*steps` the elementary steps it took (table cells filled, bytes compared,
  // greedy back-steps, values copied). At most (path bytes + 2) x (2 x pattern bytes + 64): linear
  // in the path for a bounded pattern (fuzz/watch_pattern_fuzz.cpp asserts it).
  std::optional<Match> match(std::string_view relative, std::size_t* steps) const;
  int depth() const { return static_cast<int>(segments_.size()) - 1; }  // levels below watch.dir

 private:
  PassPattern() = default;
  enum class Kind { literal, frame, pass };
  struct Token {
    Kind kind;
    std::string text;  // literal bytes
    int min = 1;       // placeholders: minimum length
  };
  using Segment = std::vector<Token>;
  std::vector<Segment> segments_;
};

}  // namespace proden::daemon
