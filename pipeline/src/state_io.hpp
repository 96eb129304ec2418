// Little binary writer/reader for the persisted frame state (FrameAccumulator, AovAccumulator):
// trivially copyable values, length-prefixed arrays and strings, in host byte order. The reader
// refuses truncated or inconsistent data with InputError (unreadable, subject "frame state").
#pragma once

#include <cmath>
#include <cstdint>
#include <cstring>
#include <span>
#include <string>
#include <type_traits>
#include <vector>

#include "proden/error.hpp"

namespace proden::detail {

class Writer {
 public:
  template <class T>
  void put(const T& v) {
    static_assert(std::is_trivially_copyable_v<T>);
    const auto* p = reinterpret_cast<const std::uint8_t*>(&v);
    out.insert(out.end(), p, p + sizeof(T));
  }
  template <class T>
  void vec(const std::vector<T>& v) {
    put<std::uint64_t>(v.size());
    const auto* p = reinterpret_cast<const std::uint8_t*>(v.data());
    out.insert(out.end(), p, p + v.size() * sizeof(T));
  }
  void str(const std::string& s) {
    put<std::uint64_t>(s.size());
    out.insert(out.end(), s.begin(), s.end());
  }
  std::vector<std::uint8_t> out;
};

class Reader {
 public:
  explicit Reader(std::span<const std::uint8_t> b) : bytes(b) {}
  [[noreturn]] static void fail(const std::string& why) {
    throw InputError(InputErrorKind::unreadable, "frame state", why);
  }
  void need(std::size_t n) const {
    if (n > bytes.size() - pos) fail("truncated frame state");
  }
  template <class T>
  T get() {
    need(sizeof(T));
    T v;
    std::memcpy(&v, bytes.data() + pos, sizeof(T));
    pos += sizeof(T);
    return v;
  }
  template <class T>
  std::vector<T> vec(std::size_t expected) {
    const auto n = get<std::uint64_t>();
    if (n != expected) fail("inconsistent array length in frame state");
    if (n > (bytes.size() - pos) / sizeof(T)) fail("truncated frame state");
    std::vector<T> v(n);
    if (n > 0) std::memcpy(v.data(), bytes.data() + pos, n * sizeof(T));
    pos += n * sizeof(T);
    if constexpr (std::is_floating_point_v<T>) {
      // add() never stores a non-finite statistic; one here is damage, however it got past the
      // checksum (issue 11, class 9: never resume from NaN).
      for (const T x : v) {
        if (!std::isfinite(x)) fail("non-finite statistic in frame state");
      }
    }
    return v;
  }
  std::string str() {
    const auto n = get<std::uint64_t>();
    if (n > 1 << 20) fail("implausible string length in frame state");
    need(n);
    std::string s(reinterpret_cast<const char*>(bytes.data() + pos), n);
    pos += n;
    return s;
  }
  std::span<const std::uint8_t> bytes;
  std::size_t pos = 0;
};

}  // namespace proden::detail
