// Error metrics against hand-computed values.
#include <catch2/catch.hpp>

#include <limits>
#include <stdexcept>

#include "proden/metrics.hpp"

using namespace proden;

TEST_CASE("metrics match hand-computed values", "[metrics]") {
  // One pixel, i = (1, 0, 2), r = (0.5, 0, 1): differences 0.5, 0, 1.
  Image i(1, 1, 3), r(1, 1, 3);
  i.at(0, 0, 0) = 1.0f;
  i.at(0, 0, 2) = 2.0f;
  r.at(0, 0, 0) = 0.5f;
  r.at(0, 0, 2) = 1.0f;
  const ErrorMetrics m = compute_metrics(i, r);
  CHECK(m.values == 3);
  CHECK(m.mse == Approx((0.25 + 1.0) / 3));
  CHECK(m.rmse == Approx(0.6454972244));
  // relMSE: 0.25/0.26 + 0 + 1/1.01, over 3.
  CHECK(m.relmse == Approx((0.25 / 0.26 + 1.0 / 1.01) / 3));
  CHECK(m.relmse == Approx(0.6505457));
  // SMAPE: 0.5/1.51 + 0/0.01 + 1/3.01, over 3.
  CHECK(m.smape == Approx((0.5 / 1.51 + 1.0 / 3.01) / 3));
  CHECK(m.smape == Approx(0.2211176));
}

TEST_CASE("identical images have zero error and non-finite values are counted", "[metrics]") {
  Image a(4, 2, 3, 0.7f);
  const ErrorMetrics z = compute_metrics(a, a);
  CHECK(z.rmse == 0.0);
  CHECK(z.smape == 0.0);
  CHECK(z.values == 24);
  Image b = a;
  b.at(1, 1, 1) = std::numeric_limits<float>::quiet_NaN();
  b.at(0, 0, 0) = 1.7f;
  const ErrorMetrics m = compute_metrics(b, a);
  CHECK(m.nonfinite == 1);
  CHECK(m.values == 23);
  CHECK(m.mse == Approx(1.0 / 23));
}

TEST_CASE("metrics refuse mismatched images", "[metrics]") {
  CHECK_THROWS_AS(compute_metrics(Image(2, 2, 3), Image(2, 3, 3)), std::invalid_argument);
  CHECK_THROWS_AS(compute_metrics(Image(2, 2, 1), Image(2, 2, 3)), std::invalid_argument);
}

TEST_CASE("the trimmed relMSE drops the largest 0.1 % of values", "[metrics]") {
  // 1000 pixels x 3 channels = 3000 values: 3 of them (0.1 %) are dropped. Two fireflies carry
  // error 1e4 each; every other value is off by 0.1 on a reference of 1 (relative error 0.01/1.01).
  Image r(100, 10, 3, 1.0f), i(100, 10, 3, 1.1f);
  i.at(3, 4, 0) = 101.0f;
  i.at(50, 7, 2) = 101.0f;
  const ErrorMetrics m = compute_metrics(i, r);
  const double small = 0.1 * 0.1 / 1.01, big = 100.0 * 100.0 / 1.01;
  // The two fireflies and one ordinary value go; the untrimmed mean keeps them.
  CHECK(m.relmse_trimmed == Approx(small).epsilon(1e-5));
  CHECK(m.relmse == Approx((2998 * small + 2 * big) / 3000).epsilon(1e-5));
}
