// Adam (torch::optim::Adam) over per-triangle parameter tensors whose rows
// can be dropped mid-run: pruning keeps each surviving row's moments, as the
// per-scene optimisers of 3DGS and Triangle Splatting do.
#pragma once
#include <string>
#include <vector>

#include <torch/optim/adam.h>

namespace flat::mesh {

class PrunableAdam {
 public:
  // One learning rate per tensor; each tensor becomes a leaf that needs grad.
  PrunableAdam(std::vector<at::Tensor> params, std::vector<double> lrs);
  at::Tensor& param(size_t i) { return params_[i]; }
  void zero_grad() { adam_->zero_grad(); }
  void step() { adam_->step(); }
  // Keeps rows `keep` (K,) int64 of every tensor and of its Adam moments.
  void keep_rows(const at::Tensor& keep);

 private:
  std::vector<at::Tensor> params_;
  std::vector<double> lrs_;
  std::unique_ptr<torch::optim::Adam> adam_;
  void rebuild();
};

}  // namespace flat::mesh
