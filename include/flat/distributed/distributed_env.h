// Where this process sits in a data-parallel job, read from the environment
// that torchrun and SLURM-style launchers set: RANK, WORLD_SIZE, LOCAL_RANK,
// MASTER_ADDR, MASTER_PORT. With none of them set the job is one process.
#pragma once
#include <cstdint>
#include <functional>
#include <string>

namespace flat::distributed {

struct DistributedEnv {
  int64_t rank = 0, world_size = 1, local_rank = 0;  // local_rank: the GPU index on this host
  std::string master_addr = "127.0.0.1";             // rank 0's host (it serves the TCPStore)
  int port = 29500;
  bool distributed() const { return world_size > 1; }
};

// Reads the variables through `getenv` (std::getenv by default; tests pass a
// map). Throws flat::Error naming the variable and its value when it is not a
// whole number, out of range (rank >= world_size, port outside 1..65535), or
// when WORLD_SIZE > 1 comes without RANK.
DistributedEnv read_distributed_env(const std::function<const char*(const char*)>& getenv = nullptr);

}  // namespace flat::distributed
