// RANK / WORLD_SIZE / LOCAL_RANK / MASTER_ADDR / MASTER_PORT as torchrun and
// SLURM launchers set them, and the errors for values a launcher got wrong.
#include <map>

#include "flat/core/error.h"
#include "flat/distributed/distributed_env.h"
#include "test_support.h"

using flat::distributed::read_distributed_env;

namespace {

flat::distributed::DistributedEnv read(const std::map<std::string, std::string>& vars) {
  return read_distributed_env([&](const char* name) -> const char* {
    auto it = vars.find(name);
    return it == vars.end() ? nullptr : it->second.c_str();
  });
}

// Every field of `env` against `expected`, one CHECK each (a failure names the field).
void check_fields(const flat::distributed::DistributedEnv& env, const flat::distributed::DistributedEnv& expected) {
  CHECK(env.rank == expected.rank);
  CHECK(env.world_size == expected.world_size);
  CHECK(env.local_rank == expected.local_rank);
  CHECK(env.master_addr == expected.master_addr);
  CHECK(env.port == expected.port);
}

}  // namespace

TEST_CASE("distributed env: nothing set is one process", "[distributed]") {
  const auto env = read({});
  check_fields(env, {/*rank=*/0, /*world_size=*/1, /*local_rank=*/0, "127.0.0.1", 29500});
  CHECK_FALSE(env.distributed());
}

TEST_CASE("distributed env: torchrun's variables are read", "[distributed]") {
  const auto env = read({{"RANK", "3"}, {"WORLD_SIZE", "4"}, {"LOCAL_RANK", "1"}, {"MASTER_ADDR", "node7"},
                         {"MASTER_PORT", "12345"}});
  check_fields(env, {/*rank=*/3, /*world_size=*/4, /*local_rank=*/1, "node7", 12345});
  CHECK(env.distributed());
  // Without LOCAL_RANK a one-host job's rank is its GPU.
  CHECK(read({{"RANK", "1"}, {"WORLD_SIZE", "2"}}).local_rank == 1);
}

TEST_CASE("distributed env: malformed values name the variable", "[distributed]") {
  using Vars = std::map<std::string, std::string>;
  auto message = [](const Vars& vars) {
    try {
      read(vars);
    } catch (const flat::Error& e) {
      return std::string(e.what());
    }
    return std::string("no error");
  };
  CHECK_THAT(message({{"RANK", "x1"}, {"WORLD_SIZE", "2"}}), FLAT_CONTAINS("RANK='x1'"));
  CHECK_THAT(message({{"RANK", "1 "}, {"WORLD_SIZE", "2"}}), FLAT_CONTAINS("RANK='1 '"));
  CHECK_THAT(message({{"RANK", "2"}, {"WORLD_SIZE", "2"}}), FLAT_CONTAINS("RANK=2 is out of range [0, 1]"));
  CHECK_THAT(message({{"WORLD_SIZE", "0"}}), FLAT_CONTAINS("WORLD_SIZE=0"));
  CHECK_THAT(message({{"WORLD_SIZE", ""}}), FLAT_CONTAINS("WORLD_SIZE=''"));
  CHECK_THAT(message({{"WORLD_SIZE", "2"}}), FLAT_CONTAINS("RANK is not set"));
  CHECK_THAT(message({{"RANK", "0"}, {"WORLD_SIZE", "2"}, {"LOCAL_RANK", "-1"}}), FLAT_CONTAINS("LOCAL_RANK=-1"));
  CHECK_THAT(message({{"MASTER_PORT", "70000"}}), FLAT_CONTAINS("MASTER_PORT=70000"));
  CHECK_THAT(message({{"MASTER_PORT", "http"}}), FLAT_CONTAINS("MASTER_PORT='http'"));
  CHECK_THAT(message({{"MASTER_ADDR", ""}}), FLAT_CONTAINS("MASTER_ADDR"));
}
