// hash_fd: an upload's content hash read through its descriptor in chunks equals hash_bytes of
// the whole body (the upload idempotency rule compares them, docs/api.md); the hashes it and the
// frame state rest on (proden/hash.hpp).
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

TEST_CASE("Checksum: pieces of any size give checksum_bytes of the whole; it is XXH3-64",
          "[daemon][files]") {
  std::mt19937_64 rng(9);
  for (const std::size_t n : {0u, 1u, 7u, 8u, 9u, 63u, 1000u, 4099u, 70000u}) {
    std::vector<unsigned char> bytes(n);
    for (auto& b : bytes) b = static_cast<unsigned char>(rng());
    const std::uint64_t whole = checksum_bytes(bytes, 5);
    CHECK(whole != checksum_bytes(bytes, 6));  // the seed counts
    for (const std::size_t piece : {1u, 3u, 8u, 13u, 4096u, 65536u}) {
      Checksum h(5);
      for (std::size_t at = 0; at < n; at += piece) {
        h.update({bytes.data() + at, std::min(piece, n - at)});
      }
      CHECK(h.finish() == whole);
    }
  }
  // XXH3-64 of no bytes, seed 0: the value in xxHash's own test vectors.
  CHECK(checksum_bytes({}) == 0x2D06800538D394C2ull);
  CHECK(hash_with(HashKind::xxh3, {}, 3) == checksum_bytes({}, 3));
  CHECK(hash_with(HashKind::legacy, {}, 3) == hash_bytes({}, 3));
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
