#include "flat/optim/adamw.h"

#include <cmath>
#include <set>

#include "flat/core/error.h"
#include "flat/core/shape.h"

#if FLAT_WITH_CUDA
#include <ATen/cuda/CUDAContext.h>
#include <c10/cuda/CUDAGuard.h>

#include "optim/cuda/adamw8bit_step.h"
#endif

namespace flat::optim {

AdamW::AdamW(std::vector<std::pair<std::string, at::Tensor>> params, AdamWOptions options) : options_(options) {
  FLAT_CHECK(options_.state_bits == 32 || options_.state_bits == 8,
             "AdamW: state_bits must be 32 or 8, got " + std::to_string(options_.state_bits));
  for (auto& [name, p] : params) {
    FLAT_CHECK(p.is_floating_point(), "AdamW: parameter '" + name + "' is not floating point");
    Slot s;
    s.name = name;
    s.param = p;
    slots_.push_back(s);
  }
}

bool AdamW::quantised(const Slot& s) const {
  return options_.state_bits == 8 && s.param.numel() >= options_.min_8bit_numel;
}

void AdamW::ensure_state(Slot& s) {
  if (s.has_state()) return;
  s.step = at::zeros({}, s.param.options().dtype(at::kFloat));
  s.steps = 0;
  if (quantised(s)) {
    auto zeros = at::zeros({s.param.numel()}, s.param.options().dtype(at::kFloat));
    s.exp_avg_q8 = quantise_blockwise(zeros, /*is_signed=*/true);
    s.exp_avg_sq_q8 = quantise_blockwise(zeros, /*is_signed=*/false);
    return;
  }
  s.exp_avg = at::zeros_like(s.param, at::MemoryFormat::Preserve);
  s.exp_avg_sq = at::zeros_like(s.param, at::MemoryFormat::Preserve);
}

void AdamW::update_8bit(Slot& s, const at::Tensor& grad, double lr) {
  // Dequantise, the fp32 update of the reference path, quantise again.
  const auto& o = options_;
  auto g = grad.to(at::kFloat);
  auto m = dequantise_blockwise(s.exp_avg_q8, s.param.sizes());
  auto v = dequantise_blockwise(s.exp_avg_sq_q8, s.param.sizes());
  s.step.add_(1);
  const double t = s.step.item<double>();
  s.steps = t;
  s.param.mul_(1 - lr * o.weight_decay);
  m.lerp_(g, 1 - o.beta1);
  v.mul_(o.beta2).addcmul_(g, g, 1 - o.beta2);
  const double bias1 = 1 - std::pow(o.beta1, t), bias2 = 1 - std::pow(o.beta2, t);
  auto denom = (v.sqrt() / std::sqrt(bias2)).add_(o.eps);
  s.param.addcdiv_(m.to(s.param.scalar_type()), denom.to(s.param.scalar_type()), -lr / bias1);
  s.exp_avg_q8 = quantise_blockwise(m, true);
  s.exp_avg_sq_q8 = quantise_blockwise(v, false);
}

bool AdamW::fused_8bit_available() { return FLAT_WITH_CUDA; }

bool AdamW::fused_8bit(const Slot& s, const at::Tensor& grad) const {
  // The kernel walks parameter, gradient and codes as flat arrays.
  auto dtype_ok = [](const at::Tensor& x) {
    return x.scalar_type() == at::kFloat || x.scalar_type() == at::kBFloat16;
  };
  auto state_ok = [&](const QuantisedTensor& q) {
    return q.codes.device() == s.param.device() && q.codes.is_contiguous() && q.absmax.is_contiguous() &&
           q.absmax.scalar_type() == at::kFloat && reinterpret_cast<uintptr_t>(q.codes.data_ptr()) % 8 == 0;
  };
  return fused_8bit_available() && options_.fused_8bit && s.param.is_cuda() && grad.device() == s.param.device() &&
         dtype_ok(s.param) && dtype_ok(grad) && s.param.is_contiguous() && grad.is_contiguous() &&
         grad.numel() == s.param.numel() && state_ok(s.exp_avg_q8) && state_ok(s.exp_avg_sq_q8);
}

void AdamW::update_8bit_fused(Slot& s, const at::Tensor& grad, double lr) {
#if FLAT_WITH_CUDA
  // The scalars of update_8bit, rounded to float where ATen rounds them.
  const auto& o = options_;
  const double t = s.steps + 1;
  const double bias1 = 1 - std::pow(o.beta1, t), bias2 = 1 - std::pow(o.beta2, t);
  const auto& signed_map = dynamic_map_tables(true, s.param.device());
  const auto& unsigned_map = dynamic_map_tables(false, s.param.device());
  cuda::AdamW8bitArgs a;
  a.param = s.param.data_ptr();
  a.grad = grad.data_ptr();
  a.param_bf16 = s.param.scalar_type() == at::kBFloat16;
  a.grad_bf16 = grad.scalar_type() == at::kBFloat16;
  a.m_codes = s.exp_avg_q8.codes.data_ptr<uint8_t>();
  a.v_codes = s.exp_avg_sq_q8.codes.data_ptr<uint8_t>();
  a.m_absmax = s.exp_avg_q8.absmax.data_ptr<float>();
  a.v_absmax = s.exp_avg_sq_q8.absmax.data_ptr<float>();
  a.m_map = signed_map.values.data_ptr<float>();
  a.m_midpoints = signed_map.midpoints.data_ptr<float>();
  a.v_map = unsigned_map.values.data_ptr<float>();
  a.v_midpoints = unsigned_map.midpoints.data_ptr<float>();
  a.step = s.step.data_ptr<float>();
  a.numel = s.param.numel();
  a.t = float(t);
  a.decay = float(1 - lr * o.weight_decay);
  a.lerp_weight = float(1 - o.beta1);
  a.beta2 = float(o.beta2);
  a.one_minus_beta2 = float(1 - o.beta2);
  a.inv_sqrt_bias2 = 1.0f / float(std::sqrt(bias2));  // div_true's CPU-scalar divisor: a float reciprocal
  a.eps = float(o.eps);
  a.step_size = float(-lr / bias1);
  const c10::cuda::CUDAGuard guard(s.param.device());
  const cudaError_t err = cuda::launch_adamw8bit_step(a, at::cuda::getCurrentCUDAStream());
  FLAT_CHECK(err == cudaSuccess,
             "AdamW: the fused 8-bit step of '" + s.name + "' failed: " + std::string(cudaGetErrorString(err)));
  // Written through raw pointers: bump the versions as the in-place ops would.
  for (const auto* x : {&s.param, &s.step, &s.exp_avg_q8.codes, &s.exp_avg_q8.absmax, &s.exp_avg_sq_q8.codes,
                        &s.exp_avg_sq_q8.absmax})
    x->unsafeGetTensorImpl()->bump_version();
  s.steps = t;
  ++fused_8bit_updates_;
#else
  (void)grad;
  (void)lr;
  FLAT_CHECK(false, "AdamW: the fused 8-bit step of '" + s.name + "' needs a build with FLAT_WITH_CUDA");
#endif
}

std::vector<at::Tensor> AdamW::grads() const {
  std::vector<at::Tensor> g;
  for (const auto& s : slots_)
    if (s.param.grad().defined()) g.push_back(s.param.grad());
  return g;
}

void AdamW::zero_grad() {
  for (auto& s : slots_) s.param.mutable_grad() = at::Tensor();
}

void AdamW::step(double lr) {
  at::NoGradGuard no_grad;
  const auto& o = options_;
  std::vector<at::Tensor> ps, gs, ms, vs, ts;
  for (auto& s : slots_) {
    const auto& g = s.param.grad();
    if (!g.defined()) continue;
    ensure_state(s);
    if (quantised(s)) {
      if (fused_8bit(s, g))
        update_8bit_fused(s, g, lr);
      else
        update_8bit(s, g, lr);
      continue;
    }
    // The fused kernel walks params, grads and moments as flat arrays: only
    // when they share one dense layout.
    const bool fusable = o.fused && (s.param.is_cuda() || s.param.is_cpu()) && s.param.scalar_type() == at::kFloat &&
                         g.scalar_type() == at::kFloat && s.param.is_non_overlapping_and_dense() &&
                         g.strides() == s.param.strides() && s.exp_avg.strides() == s.param.strides();
    if (fusable) {
      ps.push_back(s.param), gs.push_back(g), ms.push_back(s.exp_avg), vs.push_back(s.exp_avg_sq);
      ts.push_back(s.step);
      s.steps += 1;
      continue;
    }
    // The reference update (CPU, or a dtype the fused kernel does not take).
    s.step.add_(1);
    const double t = s.step.item<double>();
    s.steps = t;
    s.param.mul_(1 - lr * o.weight_decay);
    s.exp_avg.lerp_(g, 1 - o.beta1);
    s.exp_avg_sq.mul_(o.beta2).addcmul_(g, g, 1 - o.beta2);
    const double bias1 = 1 - std::pow(o.beta1, t), bias2 = 1 - std::pow(o.beta2, t);
    auto denom = (s.exp_avg_sq.sqrt() / std::sqrt(bias2)).add_(o.eps);
    s.param.addcdiv_(s.exp_avg, denom, -lr / bias1);
  }
  if (!ps.empty()) {
    // The kernel reads the step counts as they are (PyTorch's fused AdamW
    // increments them first, as here); a count of 0 would divide by 1 - b^0 = 0.
    at::_foreach_add_(ts, 1);
    at::_fused_adamw_(ps, gs, ms, vs, /*max_exp_avg_sqs=*/{}, ts, lr, o.beta1, o.beta2, o.weight_decay, o.eps,
                      /*amsgrad=*/false, /*maximize=*/false);
    // ATen's fused kernel writes in place without bumping the version
    // counters (checked on 2.11). Caches keyed on a weight's version (the
    // upsamples' subpixel filters) would then keep serving the weights of
    // their first use: the trainer's validation decoded with step-0 filters
    // (issue #44's "falling" VAE and its two held-out numbers).
    for (const auto& list : {ps, ms, vs, ts})
      for (const auto& x : list) x.unsafeGetTensorImpl()->bump_version();
  }
}

TensorMap AdamW::state() const {
  TensorMap m;
  for (const auto& s : slots_) {
    if (!s.has_state()) continue;
    if (s.exp_avg_q8.codes.defined()) {
      m["exp_avg.q8." + s.name] = s.exp_avg_q8.codes.cpu();
      m["exp_avg.absmax." + s.name] = s.exp_avg_q8.absmax.cpu();
      m["exp_avg_sq.q8." + s.name] = s.exp_avg_sq_q8.codes.cpu();
      m["exp_avg_sq.absmax." + s.name] = s.exp_avg_sq_q8.absmax.cpu();
      m["step." + s.name] = s.step.detach().cpu();
      continue;
    }
    m["exp_avg." + s.name] = s.exp_avg.detach().cpu();
    m["exp_avg_sq." + s.name] = s.exp_avg_sq.detach().cpu();
    m["step." + s.name] = s.step.detach().cpu();
  }
  return m;
}

void AdamW::load_state(const TensorMap& state, const std::string& label) {
  std::set<std::string> used;
  auto take = [&](const std::string& key) -> const at::Tensor* {
    auto it = state.find(key);
    if (it == state.end()) return nullptr;
    used.insert(key);
    return &it->second;
  };
  at::NoGradGuard no_grad;
  for (auto& s : slots_) {
    s.exp_avg = s.exp_avg_sq = s.step = at::Tensor();
    s.exp_avg_q8 = s.exp_avg_sq_q8 = QuantisedTensor{};
    const at::Tensor* t = take("step." + s.name);
    // Either form of the moments, as fp32 tensors shaped like the parameter.
    at::Tensor m, v;
    const at::Tensor *m32 = take("exp_avg." + s.name), *v32 = take("exp_avg_sq." + s.name);
    const at::Tensor *mq = take("exp_avg.q8." + s.name), *ma = take("exp_avg.absmax." + s.name);
    const at::Tensor *vq = take("exp_avg_sq.q8." + s.name), *va = take("exp_avg_sq.absmax." + s.name);
    const int full = int(m32 != nullptr) + int(v32 != nullptr), q8 = int(mq && ma) + int(vq && va);
    if (!t && full == 0 && !mq && !ma && !vq && !va) continue;  // not updated yet
    FLAT_CHECK(t && (full == 2 || q8 == 2) && full + q8 == 2,
               label + ": optimiser state of '" + s.name + "' is incomplete");
    FLAT_CHECK(t->numel() == 1, label + ": optimiser tensor 'step." + s.name + "' is not a scalar");
    if (full == 2) {
      for (const auto& [key, x] : {std::pair<std::string, const at::Tensor*>{"exp_avg." + s.name, m32},
                                   {"exp_avg_sq." + s.name, v32}})
        FLAT_CHECK(x->sizes() == s.param.sizes(), label + ": optimiser tensor '" + key + "' has shape " +
                                                      shape_str(*x) + ", the parameter has " + shape_str(s.param));
      m = m32->to(s.param.device(), at::kFloat);
      v = v32->to(s.param.device(), at::kFloat);
    } else {
      const int64_t blocks = (s.param.numel() + kQuantBlock - 1) / kQuantBlock;
      for (const auto* x : {mq, vq})
        FLAT_CHECK(x->scalar_type() == at::kByte && x->numel() == blocks * kQuantBlock,
                   label + ": 8-bit optimiser state of '" + s.name + "' has " + std::to_string(x->numel()) +
                       " codes, the parameter needs " + std::to_string(blocks * kQuantBlock));
      for (const auto* x : {ma, va})
        FLAT_CHECK(x->numel() == blocks, label + ": 8-bit optimiser state of '" + s.name + "' has " +
                                             std::to_string(x->numel()) + " block scales, expected " +
                                             std::to_string(blocks));
      // Copies (never the caller's tensors): the fused step updates them in place.
      auto own = [&](const at::Tensor* x, at::ScalarType dtype) {
        return x->to(s.param.device(), dtype, /*non_blocking=*/false, /*copy=*/true).contiguous();
      };
      QuantisedTensor qm{own(mq, at::kByte), own(ma, at::kFloat), s.param.numel(), true};
      QuantisedTensor qv{own(vq, at::kByte), own(va, at::kFloat), s.param.numel(), false};
      if (quantised(s)) {  // kept as they are: no second rounding
        s.exp_avg_q8 = qm;
        s.exp_avg_sq_q8 = qv;
      } else {
        m = dequantise_blockwise(qm, s.param.sizes());
        v = dequantise_blockwise(qv, s.param.sizes());
      }
    }
    s.step = t->reshape({}).to(s.param.device(), at::kFloat).clone();
    s.steps = t->to(at::kFloat).item<double>();
    if (m.defined()) {
      if (quantised(s)) {
        s.exp_avg_q8 = quantise_blockwise(m, true);
        s.exp_avg_sq_q8 = quantise_blockwise(v, false);
      } else {
        s.exp_avg = at::empty_like(s.param, at::MemoryFormat::Preserve).copy_(m);
        s.exp_avg_sq = at::empty_like(s.param, at::MemoryFormat::Preserve).copy_(v);
      }
    }
  }
  for (const auto& [name, tensor] : state)
    FLAT_CHECK(used.count(name), label + ": optimiser tensor '" + name + "' matches no parameter of this model");
}

int64_t AdamW::state_bytes() const {
  int64_t n = 0;
  for (const auto& s : slots_) {
    if (!s.has_state()) continue;
    n += int64_t(s.step.nbytes()) + s.exp_avg_q8.nbytes() + s.exp_avg_sq_q8.nbytes();
    if (s.exp_avg.defined()) n += int64_t(s.exp_avg.nbytes() + s.exp_avg_sq.nbytes());
  }
  return n;
}

}  // namespace flat::optim
