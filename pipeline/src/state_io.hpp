// Little binary writers/reader for the persisted frame state (FrameAccumulator, AovAccumulator):
// trivially copyable values, length-prefixed arrays and strings, in host byte order, written
// into a buffer, counted, or streamed to a sink with their hash. The reader refuses truncated or
// inconsistent data with InputError (unreadable, subject "frame state").
#pragma once

#include <cmath>
#include <cstdint>
#include <cstring>
#include <functional>
#include <span>
#include <string>
#include <type_traits>
#include <vector>

#include "proden/error.hpp"
#include "proden/hash.hpp"

namespace proden::detail {

// put / vec / str for a writer D, in terms of its bytes(span): the one place the layout of a
// value, an array (u64 length + raw values) and a string (u64 length + bytes) is written.
template <class D>
class Put {
 public:
  template <class T>
  void put(const T& v) {
    static_assert(std::is_trivially_copyable_v<T>);
    self().bytes({reinterpret_cast<const std::uint8_t*>(&v), sizeof(T)});
  }
  template <class T>
  void vec(const std::vector<T>& v) {
    put<std::uint64_t>(v.size());
    self().bytes({reinterpret_cast<const std::uint8_t*>(v.data()), v.size() * sizeof(T)});
  }
  void str(const std::string& s) {
    put<std::uint64_t>(s.size());
    self().bytes({reinterpret_cast<const std::uint8_t*>(s.data()), s.size()});
  }

 private:
  D& self() { return static_cast<D&>(*this); }
};

// Into one buffer.
class Writer : public Put<Writer> {
 public:
  void bytes(std::span<const std::uint8_t> b) { out.insert(out.end(), b.begin(), b.end()); }
  std::vector<std::uint8_t> out;
};

// Counts the bytes only: the size a streamed state will have, known before it is hashed.
class SizeCounter : public Put<SizeCounter> {
 public:
  void bytes(std::span<const std::uint8_t> b) { n += b.size(); }
  std::size_t n = 0;
};

// Hands the bytes to a sink in pieces, checksumming them as they go (checksum_bytes of the whole,
// `seed`): small fields are gathered into a buffer, arrays go to the sink straight from their
// planes, so a state of a few hundred MB is never copied whole. `also`, if given, is a checksum
// kept over the same bytes (the checksum appended too), each piece given to both in turn.
class StreamWriter : public Put<StreamWriter> {
 public:
  using Sink = std::function<void(std::span<const std::uint8_t>)>;
  StreamWriter(const Sink& sink, std::uint64_t seed, Checksum* also = nullptr)
      : sink_(sink), hash_(seed), also_(also) {}
  void bytes(std::span<const std::uint8_t> b) {
    if (b.size() < kDirect) {
      buf_.insert(buf_.end(), b.begin(), b.end());
      if (buf_.size() >= kDirect) flush();
      return;
    }
    flush();
    emit(b);
  }
  // Flushes the body, then appends its u64 hash (not itself hashed).
  void finish() {
    flush();
    const std::uint64_t h = hash_.finish();
    const std::span<const std::uint8_t> tail{reinterpret_cast<const std::uint8_t*>(&h), sizeof h};
    if (also_) also_->update(tail);
    sink_(tail);
  }

 private:
  static constexpr std::size_t kDirect = 64 << 10;
  void flush() {
    if (buf_.empty()) return;
    emit(buf_);
    buf_.clear();
  }
  void emit(std::span<const std::uint8_t> b) {
    hash_.update(b);
    if (also_) also_->update(b);
    sink_(b);
  }
  const Sink& sink_;
  Checksum hash_;
  Checksum* also_;
  std::vector<std::uint8_t> buf_;
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
