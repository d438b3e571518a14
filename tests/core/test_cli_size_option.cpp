// cli::parse_size_option: the --size HxW option of flat_eval, flat_infer and
// flat_latents, one parser and one usage error for all of them.
#include "flat/core/cli.h"
#include "test_support.h"

TEST_CASE("cli: a --size HxW option is parsed, left alone when empty, else a usage error", "[core][cli]") {
  int64_t height = 7, width = 9;
  flat::cli::parse_size_option("", height, width, "tool");
  CHECK(height == 7);
  CHECK(width == 9);
  flat::cli::parse_size_option("176x320", height, width, "tool");
  CHECK(height == 176);
  CHECK(width == 320);
  CHECK_THROWS_AS(flat::cli::parse_size_option("16by24", height, width, "tool"), flat::cli::UsageError);
  CHECK_THROWS_WITH(flat::cli::parse_size_option("16by24", height, width, "tool"),
                    FLAT_CONTAINS("tool: --size must be HxW (e.g. 176x320), got '16by24'"));
}
