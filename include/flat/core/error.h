// The one exception type of the project. Messages name the file, key or shape
// at fault; apps catch it at main() and exit nonzero with the message.
#pragma once
#include <stdexcept>
#include <string>

namespace flat {

class Error : public std::runtime_error {
 public:
  using std::runtime_error::runtime_error;
};

[[noreturn]] inline void fail(const std::string& message) { throw Error(message); }

// Cheap precondition check: FLAT_CHECK(x.dim() == 4, "rays: expected (V,H,W,3), got " + shape_str(x)).
#define FLAT_CHECK(cond, message)      \
  do {                                 \
    if (!(cond)) ::flat::fail(message); \
  } while (0)

// For the outermost catch (...) of a program's main(): logs the exception in
// flight (a flat::Error as is, anything else as "unexpected error: ...") and
// returns the exit status 1.
int report_current_error();

}  // namespace flat
