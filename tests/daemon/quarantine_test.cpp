// Quarantine: records keyed by (frame, pass) and identified by size+mtime, their JSON form, and
// the retry policy.
#include <catch2/catch.hpp>

#include <filesystem>
#include <new>
#include <system_error>

#include "daemon/quarantine.hpp"
#include "proden/error.hpp"

using namespace proden;
using namespace proden::daemon;

namespace {

Failure classify(const std::function<void()>& thrower) {
  try {
    thrower();
  } catch (...) {
    return classify_current_exception();
  }
  FAIL("nothing thrown");
  return {};
}

}  // namespace

TEST_CASE("Quarantine: the same file is blocked, a changed one admitted", "[daemon][quarantine]") {
  Quarantine q;
  q.add(1, "04", {"/w/04.exr", "unreadable", "garbage", "t", 100, 5});
  CHECK(q.contains(1, "04"));
  CHECK(q.blocks(1, "04", 100, 5));
  CHECK_FALSE(q.blocks(1, "04", 100, 6));
  CHECK_FALSE(q.blocks(2, "04", 100, 5));
  CHECK_FALSE(q.admit(1, "04", 100, 5));
  CHECK(q.contains(1, "04"));
  CHECK(q.admit(1, "04", 101, 5));  // rewritten: a new chance, record cleared
  CHECK_FALSE(q.contains(1, "04"));
}

TEST_CASE("Quarantine: records of one frame and the JSON round-trip", "[daemon][quarantine]") {
  Quarantine q;
  q.add(1, "a", {"/w/a.exr", "duplicate", "same as b", "t1", 1, 2});
  q.add(2, "b", {"/w/b.exr", "size_mismatch", "8x8 vs 4x4", "t2", 3, 4});
  const auto one = q.of_frame(1);
  REQUIRE(one.size() == 1);
  CHECK(one[0]["pass"] == "a");
  CHECK(one[0]["kind"] == "duplicate");
  CHECK(one[0]["path"] == "/w/a.exr");
  const Quarantine back = Quarantine::from_json(q.to_json());
  CHECK(back.to_json() == q.to_json());
  CHECK(back.blocks(2, "b", 3, 4));
}

TEST_CASE("Quarantine: damaged records are dropped, the good ones kept", "[daemon][quarantine]") {
  Quarantine q;
  q.add(2, "b", {"/w/b.exr", "duplicate", "same as a", "t", 3, 4});
  nlohmann::json j = q.to_json();
  j.push_back({{"frame", "seven"}, {"pass", "c"}});  // a wrong type and missing fields
  j.push_back(42);
  const Quarantine back = Quarantine::from_json(j);
  CHECK(back.blocks(2, "b", 3, 4));
  CHECK(back.to_json().size() == 1);
  CHECK(Quarantine::from_json(nlohmann::json::object()).to_json().empty());
}

TEST_CASE("Quarantine: failures are classified", "[daemon][quarantine]") {
  const Failure bad =
      classify([] { throw InputError(InputErrorKind::size_mismatch, "p.exr", "8x8 vs 4x4"); });
  CHECK(bad.cls == ErrorClass::bad_input);
  CHECK(bad.kind == "size_mismatch");
  CHECK(bad.message == "8x8 vs 4x4");
  const Failure other = classify([] { throw std::logic_error("bug"); });
  CHECK(other.cls == ErrorClass::internal);
  CHECK(other.kind == "internal");
  CHECK(other.message == "bug");
  CHECK(classify([] { throw std::bad_alloc(); }).cls == ErrorClass::transient);
  CHECK(classify([] { throw std::system_error(EIO, std::generic_category()); }).cls ==
        ErrorClass::transient);
  CHECK(classify([] {
          throw std::filesystem::filesystem_error("read",
                                                  std::make_error_code(std::errc::io_error));
        }).cls == ErrorClass::transient);
  CHECK(classify([] { throw 42; }).cls == ErrorClass::internal);
}

TEST_CASE("RetryPolicy: transient and internal failures are retried, never quarantined",
          "[daemon][quarantine]") {
  RetryPolicy policy;
  policy.max_attempts = 2;
  for (const auto cls : {ErrorClass::transient, ErrorClass::internal}) {
    const Failure f{cls, "transient", "EIO"};
    for (int attempts : {1, 2, 10, 1000}) {
      CHECK(policy.decide(f, attempts, false) == RetryPolicy::Action::retry);
      CHECK(policy.decide(f, attempts, true) == RetryPolicy::Action::retry);
    }
  }
}

TEST_CASE("RetryPolicy: the back-off doubles up to its cap", "[daemon][quarantine]") {
  RetryPolicy policy;
  policy.base = std::chrono::milliseconds(1000);
  policy.cap = std::chrono::milliseconds(5000);
  CHECK(policy.backoff(1).count() == 1000);
  CHECK(policy.backoff(2).count() == 2000);
  CHECK(policy.backoff(3).count() == 4000);
  CHECK(policy.backoff(4).count() == 5000);
  CHECK(policy.backoff(1000).count() == 5000);
}

TEST_CASE("RetryPolicy: unreadable watched files get max_attempts chances",
          "[daemon][quarantine]") {
  RetryPolicy policy;
  policy.max_attempts = 3;
  const Failure unreadable{ErrorClass::bad_input, "unreadable", "truncated"};
  CHECK(policy.decide(unreadable, 1, false) == RetryPolicy::Action::retry);
  CHECK(policy.decide(unreadable, 2, false) == RetryPolicy::Action::retry);
  CHECK(policy.decide(unreadable, 3, false) == RetryPolicy::Action::quarantine);
  // An upload is complete when stored: unreadable is final.
  CHECK(policy.decide(unreadable, 1, true) == RetryPolicy::Action::quarantine);
  // Other bad input is final at once.
  const Failure dup{ErrorClass::bad_input, "duplicate", "same pixels"};
  CHECK(policy.decide(dup, 1, false) == RetryPolicy::Action::quarantine);
}
