#include "flat/train/data_parallel.h"

#include <cmath>

#include <spdlog/fmt/fmt.h>
#include <torch/nn/module.h>

#include "flat/core/error.h"
#include "flat/distributed/weights_in_sync.h"

namespace flat::train {

std::string resolve_backend(const std::string& backend, const at::Device& device) {
  if (backend != "auto") return backend;
  if (device.is_cuda()) return "nccl";
  return distributed::gloo_backend_available() ? "gloo" : "store";
}

DataParallel::DataParallel(const DistributedConfig& config, const distributed::DistributedEnv& env,
                           const at::Device& device)
    : backend_(resolve_backend(config.backend, device)), device_(device), overlap_(config.overlap) {
  FLAT_CHECK(backend_ != "nccl" || device.is_cuda(),
             "distributed.backend: nccl needs device: cuda (use gloo or auto on the CPU)");
  FLAT_CHECK(backend_ == "nccl" || !device.is_cuda(),
             "distributed.backend: " + backend_ + " on CUDA would move every gradient through the host; use nccl (or auto)");
  sync_options_.bucket_bytes = std::max<int64_t>(1, int64_t(config.bucket_mb * double(1 << 20)));
  sync_options_.bf16_wire = config.grad_dtype == "bf16";
  const auto timeout = std::chrono::milliseconds(int64_t(std::ceil(config.timeout_seconds * 1000)));
  group_ = distributed::init_process_group(env, backend_, timeout, /*watch_peers=*/true);
}

void DataParallel::share_weights(torch::nn::Module& model) {
  std::vector<at::Tensor> tensors = model.parameters();
  for (const auto& b : model.buffers()) tensors.push_back(b);
  distributed::broadcast_tensors(*group_, tensors, 0);
}

void DataParallel::check_weights_in_sync(torch::nn::Module& model, const std::string& when) {
  std::vector<std::pair<std::string, at::Tensor>> named;
  for (const auto& p : model.named_parameters()) named.emplace_back(p.key(), p.value());
  for (const auto& b : model.named_buffers()) named.emplace_back(b.key(), b.value());
  const auto s = distributed::check_weights_in_sync(*group_, named);
  if (s.in_sync()) return;
  std::string ranks;
  for (const auto r : s.differing_ranks) ranks += (ranks.empty() ? "" : ", ") + std::to_string(r);
  throw Error(fmt::format("data parallel: at {} the weights of rank(s) {} differ from rank 0's{}: the ranks no longer "
                          "train one model, so neither rank 0's checkpoint nor the validation (each rank scores its "
                          "share of the scenes with its own copy) describes the run. Resume from the last checkpoint "
                          "(every rank then starts from rank 0's weights) and report it",
                          when, ranks,
                          s.first_tensor.empty() ? ""
                                                 : fmt::format(" (here: '{}' sums to {:.17g}, rank 0's to {:.17g})",
                                                               s.first_tensor, s.here_sum, s.rank0_sum)));
}

int64_t DataParallel::broadcast(int64_t value) {
  at::Tensor t = at::full({1}, value, at::TensorOptions().dtype(at::kLong)).to(device_);
  group_->broadcast(t, 0);
  return t.cpu().item<int64_t>();
}

void DataParallel::reduce_gradients_of(std::vector<at::Tensor> params) {
  reducer_.reset();  // its destructor removes the hooks: before the new reducer installs its own
  reducer_ = std::make_unique<distributed::OverlappedReducer>(*group_, std::move(params), sync_options_, overlap_);
}

void DataParallel::before_backward() {
  if (reducer_) reducer_->prepare();
}

void DataParallel::after_backward() {
  if (reducer_) reducer_->finish();
}

int64_t DataParallel::buckets() const { return reducer_ ? int64_t(reducer_->sync().buckets().size()) : 0; }
int64_t DataParallel::started_in_backward() const { return reducer_ ? reducer_->started_in_backward() : 0; }

std::vector<double> DataParallel::sum(const std::vector<double>& values) {
  return distributed::sum_over_ranks(*group_, values, device_);
}

int DataParallel::agree(StepResult& result, int stop_signal) {
  const int64_t W = world_size(), r = rank();
  // [triangles, non-finite per rank..., stop signal per rank...]: one
  // collective says who failed and who was asked to stop.
  std::vector<double> first(size_t(1 + 2 * W), 0.0);
  first[0] = double(result.triangles);
  first[size_t(1 + r)] = result.finite ? 0 : 1;
  first[size_t(1 + W + r)] = stop_signal;
  first = sum(first);
  result.triangles = int64_t(std::llround(first[0]));
  int stop = 0;
  std::string failed;
  for (int64_t q = 0; q < W; ++q) {
    if (first[size_t(1 + q)] > 0) failed += (failed.empty() ? "" : ", ") + std::to_string(q);
    stop = std::max(stop, int(std::lround(first[size_t(1 + W + q)])));
  }
  if (!failed.empty()) {
    if (result.finite) result.nonfinite = "on rank(s) " + failed;
    else result.nonfinite = "on rank(s) " + failed + "; here: " + result.nonfinite;
    result.finite = false;
    result.loss = NAN;
    return stop;
  }
  // Every rank finite: the same loss terms everywhere (the config names them).
  std::vector<double> terms;
  for (const auto& [name, value] : result.terms) terms.push_back(value);
  terms = sum(terms);
  size_t i = 0;
  for (auto& [name, value] : result.terms) value = terms[i++] / double(W);
  result.loss = result.terms.count("total") ? result.terms.at("total") : result.loss;
  return stop;
}

void DataParallel::finish() { group_->shutdown(); }

}  // namespace flat::train
