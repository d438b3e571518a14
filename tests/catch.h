// Bridges Catch2 v2 (Debian 12, single header) and v3 (Ubuntu 24.04, GPU machine).
#pragma once
#if FLAT_CATCH_V3
#include <catch2/catch_all.hpp>
#define FLAT_SKIP(msg) SKIP(msg)
using Catch::Approx;
namespace Catch { using Catch::Matchers::ContainsSubstring; }
#define FLAT_CONTAINS(s) Catch::Matchers::ContainsSubstring(s)
#else
#include <catch2/catch.hpp>
#define FLAT_CONTAINS(s) Catch::Contains(s)
// v2 has no SKIP: record why and leave the test case.
#define FLAT_SKIP(msg)   \
  do {                   \
    WARN("skipped: " << msg); \
    return;              \
  } while (0)
#endif
