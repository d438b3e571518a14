// exception_text: libtorch's errors in our messages without their C++ stack
// trace (issue #45: a loader error carried 23 lines of frames); cli::run maps
// one reaching a tool's top level to exit code 1.
#include <c10/util/Exception.h>

#include "flat/core/cli.h"
#include "flat/core/error.h"
#include "flat/core/exception_text.h"
#include "test_support.h"

TEST_CASE("exception_text: a c10::Error without its stack trace, anything else as what() says", "[core][error]") {
  try {
    TORCH_CHECK(false, "the shape (2,3) is wrong");
    FAIL("TORCH_CHECK did not throw");
  } catch (const std::exception& e) {
    const std::string text = flat::exception_text(e);
    CHECK_THAT(text, FLAT_CONTAINS("the shape (2,3) is wrong"));
    CHECK_THAT(text, !FLAT_CONTAINS("Exception raised from"));
    CHECK_THAT(text, !FLAT_CONTAINS("frame #"));
  }
  CHECK(flat::exception_text(flat::Error("file.json: key 'x' is missing")) == "file.json: key 'x' is missing");
  CHECK(flat::cli::run([]() -> int { TORCH_CHECK(false, "libtorch says no"); return 0; }) == flat::cli::kExitRuntime);
}
