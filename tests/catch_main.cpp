// Catch2's own main for the unit and CLI suites, compiled once (the daemon suite has its own
// runner, tests/daemon/main.cpp).
#define CATCH_CONFIG_MAIN
#include <catch2/catch.hpp>
