#include "flat/train/adamw.h"

#include <cmath>

#include "flat/core/error.h"
#include "flat/core/shape.h"

namespace flat::train {

AdamW::AdamW(std::vector<std::pair<std::string, at::Tensor>> params, AdamWOptions options) : options_(options) {
  for (auto& [name, p] : params) {
    FLAT_CHECK(p.is_floating_point(), "AdamW: parameter '" + name + "' is not floating point");
    slots_.push_back({name, p, {}, {}, {}});
  }
}

void AdamW::ensure_state(Slot& s) {
  if (s.exp_avg.defined()) return;
  s.exp_avg = at::zeros_like(s.param, at::MemoryFormat::Preserve);
  s.exp_avg_sq = at::zeros_like(s.param, at::MemoryFormat::Preserve);
  s.step = at::zeros({}, s.param.options().dtype(at::kFloat));
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
    // The fused kernel walks params, grads and moments as flat arrays: only
    // when they share one dense layout.
    const bool fusable = o.fused && s.param.is_cuda() && s.param.scalar_type() == at::kFloat &&
                         g.scalar_type() == at::kFloat && s.param.is_non_overlapping_and_dense() &&
                         g.strides() == s.param.strides() && s.exp_avg.strides() == s.param.strides();
    if (fusable) {
      ps.push_back(s.param), gs.push_back(g), ms.push_back(s.exp_avg), vs.push_back(s.exp_avg_sq);
      ts.push_back(s.step);
      continue;
    }
    // The reference update (CPU, or a dtype the fused kernel does not take).
    s.step.add_(1);
    const double t = s.step.item<double>();
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
  }
}

TensorMap AdamW::state() const {
  TensorMap m;
  for (const auto& s : slots_) {
    if (!s.exp_avg.defined()) continue;
    m["exp_avg." + s.name] = s.exp_avg.detach().cpu();
    m["exp_avg_sq." + s.name] = s.exp_avg_sq.detach().cpu();
    m["step." + s.name] = s.step.detach().cpu();
  }
  return m;
}

void AdamW::load_state(const TensorMap& state, const std::string& label) {
  size_t used = 0;
  for (auto& s : slots_) {
    auto m = state.find("exp_avg." + s.name), v = state.find("exp_avg_sq." + s.name), t = state.find("step." + s.name);
    const int found = int(m != state.end()) + int(v != state.end()) + int(t != state.end());
    if (found == 0) {
      s.exp_avg = s.exp_avg_sq = s.step = at::Tensor();
      continue;
    }
    FLAT_CHECK(found == 3, label + ": optimiser state of '" + s.name + "' is incomplete");
    for (const auto* it : {&m, &v})
      FLAT_CHECK((*it)->second.sizes() == s.param.sizes(),
                 label + ": optimiser tensor '" + (*it)->first + "' has shape " + shape_str((*it)->second) +
                     ", the parameter has " + shape_str(s.param));
    FLAT_CHECK(t->second.numel() == 1, label + ": optimiser tensor '" + t->first + "' is not a scalar");
    at::NoGradGuard no_grad;
    s.exp_avg = at::empty_like(s.param, at::MemoryFormat::Preserve).copy_(m->second);
    s.exp_avg_sq = at::empty_like(s.param, at::MemoryFormat::Preserve).copy_(v->second);
    s.step = t->second.reshape({}).to(s.param.device(), at::kFloat).clone();
    used += 3;
  }
  if (used != state.size()) {
    for (const auto& [name, tensor] : state) {
      bool known = false;
      for (const auto& s : slots_)
        known = known || name == "exp_avg." + s.name || name == "exp_avg_sq." + s.name || name == "step." + s.name;
      FLAT_CHECK(known, label + ": optimiser tensor '" + name + "' matches no parameter of this model");
    }
  }
}

int64_t AdamW::state_bytes() const {
  int64_t n = 0;
  for (const auto& s : slots_)
    if (s.exp_avg.defined()) n += int64_t(s.exp_avg.nbytes() + s.exp_avg_sq.nbytes() + s.step.nbytes());
  return n;
}

}  // namespace flat::train
