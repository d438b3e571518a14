#include "flat/distributed/distributed_env.h"

#include <cstdlib>

#include "flat/core/error.h"

namespace flat::distributed {
namespace {

// The whole string as a base-10 integer in [lo, hi]; anything else names the variable.
int64_t parse_int(const char* name, const std::string& text, int64_t lo, int64_t hi) {
  size_t used = 0;
  int64_t v = 0;
  try {
    v = std::stoll(text, &used, 10);
  } catch (const std::exception&) {
    used = 0;
  }
  if (text.empty() || used != text.size())
    fail(std::string("distributed: ") + name + "='" + text + "' is not a whole number");
  if (v < lo || v > hi)
    fail(std::string("distributed: ") + name + "=" + text + " is out of range [" + std::to_string(lo) + ", " +
         std::to_string(hi) + "]");
  return v;
}

}  // namespace

DistributedEnv read_distributed_env(const std::function<const char*(const char*)>& getenv) {
  auto get = [&](const char* name) -> const char* { return getenv ? getenv(name) : std::getenv(name); };
  DistributedEnv env;
  if (const char* v = get("WORLD_SIZE")) env.world_size = parse_int("WORLD_SIZE", v, 1, 1 << 20);
  const char* rank = get("RANK");
  if (rank) {
    env.rank = parse_int("RANK", rank, 0, env.world_size - 1);
  } else if (env.world_size > 1) {
    // Guessing rank 0 would make every process a server of the same store.
    fail("distributed: WORLD_SIZE=" + std::to_string(env.world_size) + " but RANK is not set");
  }
  // Without LOCAL_RANK a one-host job's rank is its GPU index.
  env.local_rank = env.rank;
  if (const char* v = get("LOCAL_RANK")) env.local_rank = parse_int("LOCAL_RANK", v, 0, env.world_size - 1);
  if (const char* v = get("MASTER_ADDR")) {
    FLAT_CHECK(*v != '\0', "distributed: MASTER_ADDR is set but empty");
    env.master_addr = v;
  }
  if (const char* v = get("MASTER_PORT")) env.port = static_cast<int>(parse_int("MASTER_PORT", v, 1, 65535));
  return env;
}

}  // namespace flat::distributed
