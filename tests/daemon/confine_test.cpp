// Confinement at the moment of use (service/daemon/files.hpp): opens beneath a held root
// descriptor, with the kernel's openat2 and with the O_NOFOLLOW walk, against symlinks and
// renames swapped in after a path was accepted (issue 11, class 2).
#include <fcntl.h>
#include <sys/stat.h>
#include <unistd.h>
#include <catch2/catch.hpp>

#include <filesystem>
#include <fstream>
#include <random>

#include "daemon/files.hpp"

namespace fs = std::filesystem;
using namespace proden::daemon;

namespace {

struct Tree {
  fs::path base, root, outside;
  Tree() {
    base = fs::temp_directory_path() / ("proden-confine-" + std::to_string(std::random_device{}()));
    root = base / "root";
    outside = base / "outside";
    fs::create_directories(root / "w" / "pass_01");
    fs::create_directories(outside / "pass_01");
    write(root / "w" / "pass_01" / "a.exr", "inside");
    write(outside / "secret.exr", "SECRET");
    write(outside / "pass_01" / "a.exr", "SECRET");
    root = fs::canonical(root);
    outside = fs::canonical(outside);
  }
  ~Tree() {
    std::error_code ec;
    fs::remove_all(base, ec);
  }
  static void write(const fs::path& p, const std::string& text) { std::ofstream(p) << text; }
};

// What reading `p` through the roots gives: the text, or "E:<error>".
std::string read(const Roots& roots, const fs::path& p, Resolve how) {
  FileError err = FileError::none;
  std::string why;
  const UniqueFd fd = roots.open(p, O_RDONLY | O_NONBLOCK, err, why, how);
  if (!fd) {
    switch (err) {
      case FileError::escape:
        return "E:escape";
      case FileError::not_found:
        return "E:not_found";
      default:
        return "E:other:" + why;
    }
  }
  auto bytes = read_fd(fd.get(), 1 << 20, err, why);
  if (!bytes) return "E:read:" + why;
  return std::string(bytes->bytes.begin(), bytes->bytes.end());
}

const Resolve kModes[] = {Resolve::automatic, Resolve::walk};

}  // namespace

TEST_CASE("plain files and symlinks that stay inside a root are read", "[confine]") {
  Tree t;
  const Roots roots({t.root.string()});
  fs::create_symlink("pass_01/a.exr", t.root / "w" / "rel_link.exr");
  fs::create_symlink(t.root / "w" / "pass_01" / "a.exr", t.root / "w" / "abs_link.exr");
  fs::create_directories(t.root / "x");
  fs::create_symlink("../w/pass_01", t.root / "x" / "dirlink");
  for (Resolve how : kModes) {
    CHECK(read(roots, t.root / "w" / "pass_01" / "a.exr", how) == "inside");
    CHECK(read(roots, t.root / "w" / "rel_link.exr", how) == "inside");
    CHECK(read(roots, t.root / "w" / "abs_link.exr", how) == "inside");
    CHECK(read(roots, t.root / "x" / "dirlink" / "a.exr", how) == "inside");
    CHECK(read(roots, t.root / "w" / "nope.exr", how) == "E:not_found");
  }
}

TEST_CASE("symlinks and '..' leading out of the root are refused when used", "[confine]") {
  Tree t;
  const Roots roots({t.root.string()});
  fs::create_symlink(t.outside / "secret.exr", t.root / "w" / "abs_out.exr");
  fs::create_symlink("../../outside/secret.exr", t.root / "w" / "rel_out.exr");
  fs::create_symlink("loop2", t.root / "w" / "loop1");
  fs::create_symlink("loop1", t.root / "w" / "loop2");
  for (Resolve how : kModes) {
    INFO(static_cast<int>(how));
    CHECK(read(roots, t.root / "w" / "abs_out.exr", how) == "E:escape");
    CHECK(read(roots, t.root / "w" / "rel_out.exr", how) == "E:escape");
    CHECK(read(roots, t.root / "w" / "loop1", how).starts_with("E:"));
    CHECK(read(roots, t.root / ".." / "outside" / "secret.exr", how) == "E:escape");
    CHECK(read(roots, t.outside / "secret.exr", how) == "E:escape");
  }
}

TEST_CASE("a watch directory swapped for a symlink after it was accepted", "[confine]") {
  Tree t;
  const Roots roots({t.root.string()});
  std::string why;
  const auto accepted = roots.confine((t.root / "w").string(), why);  // job creation
  REQUIRE(accepted);
  // Later: the directory is moved away and a symlink to the outside takes its place.
  fs::rename(t.root / "w", t.root / "w_old");
  fs::create_symlink(t.outside, t.root / "w");
  for (Resolve how : kModes) {
    CHECK(read(roots, *accepted / "pass_01" / "a.exr", how) == "E:escape");
    CHECK(read(roots, *accepted / "secret.exr", how) == "E:escape");
  }
  // A subdirectory swapped the same way.
  fs::remove(t.root / "w");
  fs::rename(t.root / "w_old", t.root / "w");
  fs::rename(t.root / "w" / "pass_01", t.base / "moved_away");
  fs::create_symlink(t.outside / "pass_01", t.root / "w" / "pass_01");
  for (Resolve how : kModes)
    CHECK(read(roots, t.root / "w" / "pass_01" / "a.exr", how) == "E:escape");
}

TEST_CASE("a watched subfolder moved out of the root is not read through its old path",
          "[confine]") {
  Tree t;
  const Roots roots({t.root.string()});
  const fs::path p = t.root / "w" / "pass_01" / "a.exr";
  // The daemon holds an inotify watch on the moved directory and still builds names from its
  // old path: those names resolve inside the root again, and find nothing.
  fs::rename(t.root / "w" / "pass_01", t.outside / "moved");
  for (Resolve how : kModes) CHECK(read(roots, p, how) == "E:not_found");
}

TEST_CASE("reading through the roots: FIFOs do not block, sizes are bounded", "[confine]") {
  Tree t;
  const Roots roots({t.root.string()});
  REQUIRE(::mkfifo((t.root / "w" / "fifo.exr").c_str(), 0600) == 0);
  FileError err = FileError::none;
  std::string why;
  CHECK_FALSE(roots.read(t.root / "w" / "fifo.exr", 1 << 20, err, why));
  CHECK(err == FileError::not_regular);
  CHECK_FALSE(roots.read(t.root / "w" / "pass_01" / "a.exr", 3, err, why));
  CHECK(err == FileError::too_large);
  const auto ok = roots.read(t.root / "w" / "pass_01" / "a.exr", 100, err, why);
  REQUIRE(ok);
  CHECK(ok->size == 6);
  std::error_code ec;
  CHECK(ok->mtime_ns == mtime_ns(t.root / "w" / "pass_01" / "a.exr", ec));
}

TEST_CASE("directories are created one by one beneath the root", "[confine]") {
  Tree t;
  const Roots roots({t.root.string()});
  FileError err = FileError::none;
  std::string why;
  auto fd = roots.make_dirs(t.root / "out" / "a" / "b", err, why);
  REQUIRE(fd);
  CHECK(fs::is_directory(t.root / "out" / "a" / "b"));
  // A symlink to the outside in the middle: nothing is created out there.
  fs::create_symlink(t.outside, t.root / "evil");
  fd = roots.make_dirs(t.root / "evil" / "sub" / "deeper", err, why);
  CHECK_FALSE(fd);
  CHECK(err == FileError::escape);
  CHECK_FALSE(fs::exists(t.outside / "sub"));
  // A symlink inside the root is followed.
  fs::create_symlink("out", t.root / "alias");
  fd = roots.make_dirs(t.root / "alias" / "c", err, why);
  CHECK(fd);
  CHECK(fs::is_directory(t.root / "out" / "c"));
}

TEST_CASE("paths outside every root are refused without touching them", "[confine]") {
  Tree t;
  const Roots roots({t.root.string()});
  FileError err = FileError::none;
  std::string why;
  CHECK_FALSE(roots.open(t.outside / "secret.exr", O_RDONLY, err, why));
  CHECK(err == FileError::escape);
  CHECK_FALSE(roots.open("relative/path", O_RDONLY, err, why));
  CHECK(err == FileError::escape);
  // A sibling whose name starts like the root is not inside it.
  fs::create_directories(t.base / "rootx");
  Tree::write(t.base / "rootx" / "f", "x");
  CHECK_FALSE(roots.open(fs::path(t.root.string() + "x") / "f", O_RDONLY, err, why));
}

TEST_CASE("new files are created beneath the root without following a planted link", "[confine]") {
  Tree t;
  const Roots roots({t.root.string()});
  fs::create_symlink(t.outside / "planted.exr", t.root / "w" / "out.exr");
  for (Resolve how : kModes) {
    FileError err = FileError::none;
    std::string why;
    const auto fd =
        roots.open(t.root / "w" / "out.exr", O_WRONLY | O_CREAT | O_EXCL, err, why, how);
    CHECK_FALSE(fd);
    CHECK_FALSE(fs::exists(t.outside / "planted.exr"));
  }
}
