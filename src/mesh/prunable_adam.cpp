#include "flat/mesh/prunable_adam.h"

#include "flat/core/error.h"

namespace flat::mesh {

PrunableAdam::PrunableAdam(std::vector<at::Tensor> params, std::vector<double> lrs) : lrs_(std::move(lrs)) {
  FLAT_CHECK(params.size() == lrs_.size(), "PrunableAdam: one learning rate per tensor");
  for (auto& p : params) params_.push_back(p.detach().clone().requires_grad_(true));
  rebuild();
}

void PrunableAdam::rebuild() {
  std::vector<torch::optim::OptimizerParamGroup> groups;
  for (size_t i = 0; i < params_.size(); ++i)
    groups.emplace_back(std::vector<at::Tensor>{params_[i]},
                        std::make_unique<torch::optim::AdamOptions>(lrs_[i]));
  adam_ = std::make_unique<torch::optim::Adam>(groups, torch::optim::AdamOptions(lrs_.empty() ? 1e-3 : lrs_[0]));
}

void PrunableAdam::keep_rows(const at::Tensor& keep) {
  std::vector<std::unique_ptr<torch::optim::AdamParamState>> states;
  for (auto& p : params_) {
    auto it = adam_->state().find(p.unsafeGetTensorImpl());
    if (it == adam_->state().end()) {
      states.emplace_back();
      continue;
    }
    const auto& old = static_cast<const torch::optim::AdamParamState&>(*it->second);
    auto s = std::make_unique<torch::optim::AdamParamState>();
    s->step(old.step());
    s->exp_avg(old.exp_avg().index_select(0, keep));
    s->exp_avg_sq(old.exp_avg_sq().index_select(0, keep));
    states.push_back(std::move(s));
  }
  for (auto& p : params_) p = p.detach().index_select(0, keep).requires_grad_(true);
  rebuild();
  for (size_t i = 0; i < params_.size(); ++i)
    if (states[i]) adam_->state()[params_[i].unsafeGetTensorImpl()] = std::move(states[i]);
}

}  // namespace flat::mesh
