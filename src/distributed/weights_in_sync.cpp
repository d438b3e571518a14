#include "flat/distributed/weights_in_sync.h"

#include <torch/torch.h>

namespace flat::distributed {

WeightsSync check_weights_in_sync(ProcessGroup& group, const std::vector<std::pair<std::string, at::Tensor>>& named) {
  WeightsSync r;
  if (named.empty()) return r;
  torch::NoGradGuard no_grad;
  const auto device = named.front().second.device();
  // Two numbers per tensor, in fp64 so that one changed bit of a weight shows.
  std::vector<at::Tensor> parts;
  parts.reserve(2 * named.size());
  for (const auto& [name, t] : named) {
    const auto d = t.detach().to(device, at::kDouble);
    parts.push_back(d.sum().reshape({1}));
    parts.push_back(d.square().sum().reshape({1}));
  }
  const auto here = at::cat(parts);
  auto rank0 = here.clone();
  group.broadcast(rank0, 0);
  const auto differs = here.ne(rank0);
  // One flag per rank, summed: every rank learns who differs.
  auto flags = at::zeros({group.world_size()}, here.options());
  if (differs.any().item<bool>()) {
    flags[group.rank()] = 1;
    const int64_t k = differs.nonzero().flatten()[0].item<int64_t>();
    r.first_tensor = named[size_t(k / 2)].first;
    const auto h = here.cpu(), z = rank0.cpu();
    r.here_sum = h[k - k % 2].item<double>();
    r.rank0_sum = z[k - k % 2].item<double>();
  }
  group.allreduce_sum(flags);
  const auto f = flags.cpu();
  for (int64_t i = 0; i < group.world_size(); ++i)
    if (f[i].item<double>() > 0) r.differing_ranks.push_back(i);
  return r;
}

}  // namespace flat::distributed
