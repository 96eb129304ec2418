// hash_fd: an upload's content hash read through its descriptor in chunks equals hash_bytes of
// the whole body (the upload idempotency rule compares them, docs/api.md).
#include <fcntl.h>
#include <unistd.h>

#include <catch2/catch.hpp>
#include <fstream>
#include <random>

#include "daemon/files.hpp"
#include "proden/hash.hpp"
#include "test_support.hpp"

using namespace proden;

TEST_CASE("ByteHasher: pieces of any size give hash_bytes of the whole", "[daemon][files]") {
  std::mt19937_64 rng(7);
  for (const std::size_t n : {0u, 1u, 7u, 8u, 9u, 63u, 1000u, 4099u}) {
    std::vector<unsigned char> bytes(n);
    for (auto& b : bytes) b = static_cast<unsigned char>(rng());
    const std::uint64_t whole = hash_bytes(bytes, 5);
    for (const std::size_t piece : {1u, 3u, 8u, 13u, 4096u}) {
      ByteHasher h(n, 5);
      for (std::size_t at = 0; at < n; at += piece) {
        h.update({bytes.data() + at, std::min(piece, n - at)});
      }
      CHECK(h.finish() == whole);
    }
  }
}

TEST_CASE("ByteHasher: update_both equals two updates, in or out of step", "[daemon][files]") {
  std::mt19937_64 rng(9);
  std::vector<unsigned char> bytes(5000);
  for (auto& b : bytes) b = static_cast<unsigned char>(rng());
  // `outer` has taken `lead` bytes of its own first (a file's head before the blob): the two
  // hashers' partial words are in step when lead is a multiple of 8, out of step otherwise.
  for (const std::size_t lead : {0u, 8u, 16u, 3u, 13u}) {
    for (const std::size_t piece : {1u, 5u, 8u, 64u, 1000u, 5000u}) {
      INFO("lead " << lead << " piece " << piece);
      ByteHasher inner(bytes.size(), 3), outer(lead + bytes.size(), 4);
      outer.update({bytes.data(), lead});
      for (std::size_t at = 0; at < bytes.size(); at += piece) {
        ByteHasher::update_both(inner, outer,
                                {bytes.data() + at, std::min(piece, bytes.size() - at)});
      }
      std::vector<unsigned char> whole(bytes.begin(), bytes.begin() + static_cast<long>(lead));
      whole.insert(whole.end(), bytes.begin(), bytes.end());
      CHECK(inner.finish() == hash_bytes(bytes, 3));
      CHECK(outer.finish() == hash_bytes(whole, 4));
    }
  }
}

TEST_CASE("hash_fd: the file's hash in 1 MiB chunks; a short file is unreadable",
          "[daemon][files]") {
  test::TempDir t;
  const auto path = t.path() / "body.bin";
  std::vector<unsigned char> bytes((std::size_t{1} << 20) * 2 + 5);
  std::mt19937_64 rng(11);
  for (auto& b : bytes) b = static_cast<unsigned char>(rng());
  {
    std::ofstream out(path, std::ios::binary);
    out.write(reinterpret_cast<const char*>(bytes.data()),
              static_cast<std::streamsize>(bytes.size()));
  }
  const int fd = ::open(path.c_str(), O_RDONLY);
  REQUIRE(fd >= 0);
  CHECK(daemon::hash_fd(fd, bytes.size()) == hash_bytes(bytes));
  CHECK_FALSE(daemon::hash_fd(fd, bytes.size() + 1).has_value());
  ::close(fd);
}
