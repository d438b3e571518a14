// The message a failing call throws, for tests that check what an error says
// (its file, key, shape) rather than only that one was thrown.
#pragma once
#include <functional>
#include <string>

#include "flat/core/error.h"

namespace flat::test {

// The what() of the flat::Error that `f` throws, or "(no error)".
inline std::string error_of(const std::function<void()>& f) {
  try {
    f();
  } catch (const Error& e) {
    return e.what();
  }
  return "(no error)";
}

}  // namespace flat::test
