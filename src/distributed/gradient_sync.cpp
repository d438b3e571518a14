#include "flat/distributed/gradient_sync.h"

#include "flat/core/error.h"

namespace flat::distributed {

void broadcast_tensors(ProcessGroup& group, const std::vector<at::Tensor>& tensors, int64_t root) {
  at::NoGradGuard no_grad;
  for (const auto& t : tensors) {
    at::Tensor data = t.detach();  // shares storage: the broadcast writes the tensor itself
    group.broadcast(data, root);
  }
}

GradientSync::GradientSync(ProcessGroup& group, std::vector<at::Tensor> params, GradientSyncOptions options)
    : group_(group), params_(std::move(params)), bf16_wire_(options.bf16_wire) {
  FLAT_CHECK(options.bucket_bytes > 0, "gradient sync: bucket_bytes must be positive");
  // Reverse order: backward produces the last layers' gradients first.
  for (int64_t i = static_cast<int64_t>(params_.size()) - 1; i >= 0; --i) {
    const at::Tensor& p = params_[i];
    FLAT_CHECK(p.defined(), "gradient sync: parameter " + std::to_string(i) + " is undefined");
    bool fits = false;
    if (!buckets_.empty()) {
      const Bucket& b = buckets_.back();
      const at::Tensor& first = params_[b.params.front()];
      fits = first.scalar_type() == p.scalar_type() && first.device() == p.device() &&
             (b.numel + p.numel()) * static_cast<int64_t>(p.element_size()) <= options.bucket_bytes;
    }
    if (!fits) buckets_.emplace_back();
    buckets_.back().params.push_back(i);
    buckets_.back().numel += p.numel();
  }
  pending_.resize(buckets_.size());
}

void GradientSync::all_reduce_gradients() {
  for (size_t b = 0; b < buckets_.size(); ++b) start_bucket(b);
  for (size_t b = 0; b < buckets_.size(); ++b) finish_bucket(b);
}

void GradientSync::reduce_bucket(size_t b) {
  start_bucket(b);
  finish_bucket(b);
}

void GradientSync::start_bucket(size_t b) {
  FLAT_CHECK(b < buckets_.size(), "gradient sync: bucket " + std::to_string(b) + " of " +
                                      std::to_string(buckets_.size()));
  FLAT_CHECK(!started(b), "gradient sync: bucket " + std::to_string(b) + " started twice");
  at::NoGradGuard no_grad;
  const Bucket& bucket = buckets_[b];
  const at::Tensor& first = params_[bucket.params.front()];
  const int64_t n = static_cast<int64_t>(bucket.params.size());
  const bool bf16 = bf16_wire_ && at::isFloatingType(first.scalar_type());
  at::Tensor flat = at::empty({bucket.numel + n}, bf16 ? first.options().dtype(at::kBFloat16) : first.options());
  int64_t offset = 0;
  for (int64_t k = 0; k < n; ++k) {
    const at::Tensor& p = params_[bucket.params[k]];
    at::Tensor slot = flat.narrow(0, offset, p.numel());
    const at::Tensor& g = p.grad();
    if (g.defined()) {
      FLAT_CHECK(g.sizes() == p.sizes(), "gradient sync: a gradient's shape differs from its parameter's");
      slot.copy_(g.reshape(-1));
    } else {
      slot.zero_();
    }
    offset += p.numel();
  }
  // The presence counts in one copy (a fill per parameter would be one kernel each on a GPU).
  std::vector<float> present(size_t(n), 0.f);
  for (int64_t k = 0; k < n; ++k) present[size_t(k)] = params_[bucket.params[k]].grad().defined() ? 1.f : 0.f;
  flat.narrow(0, bucket.numel, n).copy_(at::tensor(present));
  Pending& p = pending_[b];
  p.flat = flat;
  p.work = group_.allreduce_sum_async(p.flat);
}

void GradientSync::finish_bucket(size_t b) {
  FLAT_CHECK(b < buckets_.size() && started(b), "gradient sync: bucket " + std::to_string(b) + " was not started");
  at::NoGradGuard no_grad;
  Pending pending = std::move(pending_[b]);
  pending_[b] = Pending{};
  pending.work->wait();
  const Bucket& bucket = buckets_[b];
  const int64_t n = static_cast<int64_t>(bucket.params.size());
  at::Tensor flat = pending.flat;
  // The presence counts are read on the host (a device sync) only where this
  // rank lacks a gradient: a gradient it has was counted, so it gets the mean.
  bool all_local = true;
  for (int64_t k = 0; k < n; ++k) all_local = all_local && params_[bucket.params[k]].grad().defined();
  at::Tensor counts;
  if (!all_local) counts = flat.narrow(0, bucket.numel, n).to(at::kCPU, at::kFloat);
  flat.narrow(0, 0, bucket.numel).div_(static_cast<double>(group_.world_size()));
  int64_t offset = 0;
  for (int64_t k = 0; k < n; ++k) {
    at::Tensor p = params_[bucket.params[k]];
    at::Tensor mean = flat.narrow(0, offset, p.numel()).view(p.sizes());
    offset += p.numel();
    if (!all_local && counts.data_ptr<float>()[k] == 0) continue;  // no rank had one: undefined everywhere
    if (p.grad().defined()) {
      p.mutable_grad().copy_(mean);
    } else {
      p.mutable_grad() = mean.to(p.scalar_type(), /*non_blocking=*/false, /*copy=*/true);  // a bf16 wire mean too
    }
  }
}

}  // namespace flat::distributed
