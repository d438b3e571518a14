#include "flat/distributed/gradient_sync.h"

#include <algorithm>

#include <c10/util/strides.h>

#include "flat/core/error.h"

namespace flat::distributed {

void broadcast_tensors(ProcessGroup& group, const std::vector<at::Tensor>& tensors, int64_t root) {
  at::NoGradGuard no_grad;
  for (const auto& t : tensors) {
    at::Tensor data = t.detach();  // shares storage: the broadcast writes the tensor itself
    group.broadcast(data, root);
  }
}

namespace {

// Slots start on 16 bytes: the optimisers' vectorised loops need aligned
// tensors, and a 3-value bias would otherwise misalign every slot after it.
int64_t aligned(int64_t offset, int64_t element_size) {
  const int64_t step = std::max<int64_t>(1, 16 / element_size);
  return (offset + step - 1) / step * step;
}

}  // namespace

GradientSync::GradientSync(ProcessGroup& group, std::vector<at::Tensor> params, GradientSyncOptions options)
    : group_(group), params_(std::move(params)), bf16_wire_(options.bf16_wire) {
  FLAT_CHECK(options.bucket_bytes > 0, "gradient sync: bucket_bytes must be positive");
  // A parameter listed twice (tied weights) would get two slots, one of them
  // never written by backward and read while its all-reduce may still run.
  for (size_t i = 0; i < params_.size(); ++i)
    for (size_t j = 0; j < i; ++j)
      FLAT_CHECK(!params_[i].defined() || !params_[j].defined() || !params_[i].is_same(params_[j]),
                 "gradient sync: parameters " + std::to_string(j) + " and " + std::to_string(i) +
                     " are the same tensor; list each once");
  // Reverse order: backward produces the last layers' gradients first.
  for (int64_t i = static_cast<int64_t>(params_.size()) - 1; i >= 0; --i) {
    const at::Tensor& p = params_[i];
    FLAT_CHECK(p.defined(), "gradient sync: parameter " + std::to_string(i) + " is undefined");
    bool fits = false;
    if (!buckets_.empty()) {
      const Bucket& b = buckets_.back();
      const at::Tensor& first = params_[b.params.front()];
      fits = first.scalar_type() == p.scalar_type() && first.device() == p.device() &&
             (aligned(b.numel, p.element_size()) + p.numel()) * int64_t(p.element_size()) <= options.bucket_bytes;
    }
    if (!fits) buckets_.emplace_back();
    Bucket& b = buckets_.back();
    b.params.push_back(i);
    b.offsets.push_back(aligned(b.numel, p.element_size()));
    b.numel = b.offsets.back() + p.numel();
  }
  pending_.resize(buckets_.size());
  // The buckets live as long as this object: the gradients are aliases of them.
  at::NoGradGuard no_grad;
  views_.resize(params_.size());
  bound_version_.assign(params_.size(), 0);
  for (const Bucket& bucket : buckets_) {
    const at::Tensor& first = params_[bucket.params.front()];
    const int64_t n = static_cast<int64_t>(bucket.params.size());
    flat_.push_back(at::zeros({bucket.numel + n}, first.options()));
    for (int64_t k = 0; k < n; ++k) {
      const at::Tensor& p = params_[bucket.params[k]];
      // The parameter's own layout (a channels-last conv weight gets a
      // channels-last gradient), so the optimiser's fused loops still apply.
      const c10::DimVector strides =
          p.is_non_overlapping_and_dense() ? c10::DimVector(p.strides()) : c10::contiguous_strides(p.sizes());
      // An alias of the bucket's storage, not an autograd view: optimisers
      // may detach_() a .grad (libtorch's zero_grad does), which a view forbids.
      views_[bucket.params[k]] =
          at::empty({0}, first.options()).set_(flat_.back().storage(), bucket.offsets[k], p.sizes(), strides);
    }
  }
}

bool GradientSync::is_bound(int64_t param) const {
  const at::Tensor& g = params_[param].grad();
  return g.defined() && g.unsafeGetTensorImpl() == views_[param].unsafeGetTensorImpl();
}

void GradientSync::bind_gradients() {
  at::NoGradGuard no_grad;
  for (size_t b = 0; b < buckets_.size(); ++b) {
    FLAT_CHECK(!started(b), "gradient sync: bind_gradients while bucket " + std::to_string(b) + " is in flight");
    flat_[b].zero_();  // padding included
  }
  for (size_t i = 0; i < params_.size(); ++i) {
    params_[i].mutable_grad() = views_[i];
    bound_version_[i] = views_[i]._version();
  }
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
  const int64_t n = static_cast<int64_t>(bucket.params.size());
  at::Tensor flat = flat_[b];
  Pending& pending = pending_[b];
  pending = Pending{};
  std::vector<int64_t> absent;
  for (int64_t k = 0; k < n; ++k) {
    const int64_t i = bucket.params[k];
    const at::Tensor& g = params_[i].grad();
    if (is_bound(i)) {
      // Backward accumulated into the bucket itself (an in-place add, which
      // moves the alias's version); untouched, the slot holds bind's zeros.
      if (views_[size_t(i)]._version() == bound_version_[size_t(i)]) absent.push_back(k);
      continue;
    }
    pending.all_bound = false;
    if (g.defined()) {
      FLAT_CHECK(g.sizes() == params_[i].sizes(), "gradient sync: a gradient's shape differs from its parameter's");
      views_[size_t(i)].copy_(g);  // in the slot's layout, which finish_bucket reads the mean back with
    } else {
      views_[size_t(i)].zero_();
      absent.push_back(k);
    }
  }
  // The presence counts: one fill, plus one zero per absent parameter (rare:
  // a parameter unused on this rank), never a host-to-device copy, which
  // would wait for the device.
  at::Tensor counts = flat.narrow(0, bucket.numel, n);
  counts.fill_(1);
  for (int64_t k : absent) counts.narrow(0, k, 1).zero_();
  pending.all_present = absent.empty();
  pending.wire = bf16_wire_ && at::isFloatingType(flat.scalar_type()) ? flat.to(at::kBFloat16) : flat;
  pending.work = group_.allreduce_sum_async(pending.wire);
}

void GradientSync::finish_bucket(size_t b) {
  FLAT_CHECK(b < buckets_.size() && started(b), "gradient sync: bucket " + std::to_string(b) + " was not started");
  at::NoGradGuard no_grad;
  Pending pending = std::move(pending_[b]);
  pending_[b] = Pending{};
  pending.work->wait();
  const Bucket& bucket = buckets_[b];
  const int64_t n = static_cast<int64_t>(bucket.params.size());
  at::Tensor flat = flat_[b];
  if (!pending.wire.is_same(flat)) flat.copy_(pending.wire);  // the bf16 wire's sums, back in the bucket's dtype
  flat.narrow(0, 0, bucket.numel).div_(static_cast<double>(group_.world_size()));
  if (pending.all_present && pending.all_bound) return;  // the means are in the gradients already
  // The presence counts are read on the host (a device sync) only where this
  // rank lacks a gradient: a gradient it has was counted, so it gets the mean.
  at::Tensor counts;
  if (!pending.all_present) counts = flat.narrow(0, bucket.numel, n).to(at::kCPU, at::kFloat);
  for (int64_t k = 0; k < n; ++k) {
    const int64_t i = bucket.params[k];
    at::Tensor p = params_[i];
    if (counts.defined() && counts.data_ptr<float>()[k] == 0) {
      p.mutable_grad() = at::Tensor();  // no rank had one: undefined everywhere
    } else if (!p.grad().defined()) {
      p.mutable_grad() = views_[i];  // the mean of the ranks that had one, in the parameter's dtype
    } else if (!is_bound(i)) {
      p.mutable_grad().copy_(views_[i]);
    }
  }
}

}  // namespace flat::distributed
