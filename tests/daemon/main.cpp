// Catch2 entry point of the daemon's unit tests (service/daemon parts tested without HTTP).
#define CATCH_CONFIG_MAIN
#include <catch2/catch.hpp>
