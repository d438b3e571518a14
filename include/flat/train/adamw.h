// AdamW (Loshchilov & Hutter) with its state held in plain named tensors, so a
// checkpoint stores and restores it exactly (and the 8-bit variant can share
// the interface). Paper, Implementation Details: AdamW, lr 1e-4.
//
//   p <- p - lr * wd * p
//   m <- b1 m + (1 - b1) g ;  v <- b2 v + (1 - b2) g^2
//   p <- p - lr * (m / (1 - b1^t)) / (sqrt(v / (1 - b2^t)) + eps)
//
// On CUDA the update is ATen's fused multi-tensor kernel (_fused_adamw_, as
// PyTorch's `fused=True`); on the CPU it is the loop below, op for op as
// torch.optim.AdamW's single-tensor path, so CPU runs are deterministic.
#pragma once
#include <cstdint>
#include <string>
#include <utility>
#include <vector>

#include <ATen/ATen.h>

#include "flat/core/tensor_io.h"

namespace flat::train {

struct AdamWOptions {
  double beta1 = 0.9, beta2 = 0.999, eps = 1e-8, weight_decay = 0.01;
  bool fused = true;  // CUDA: ATen's fused kernel; false: the op-by-op update everywhere
};

class AdamW {
 public:
  // Named parameters (model.named_parameters()); the names key the state.
  AdamW(std::vector<std::pair<std::string, at::Tensor>> params, AdamWOptions options);

  // One update with learning rate lr; parameters without a gradient are left alone.
  void step(double lr);
  void zero_grad();

  // The parameters' gradients (undefined ones left out), for norms and clipping.
  std::vector<at::Tensor> grads() const;

  // "exp_avg.<name>", "exp_avg_sq.<name>", "step.<name>" (CPU copies). A
  // parameter not yet updated has no entries.
  TensorMap state() const;
  // Restores state() output; throws flat::Error naming `label` and the tensor
  // on an unknown name or a shape that does not match the parameter.
  void load_state(const TensorMap& state, const std::string& label);
  // Bytes of optimiser state held now.
  int64_t state_bytes() const;

 private:
  struct Slot {
    std::string name;
    at::Tensor param, exp_avg, exp_avg_sq, step;  // step: float32 scalar on the param's device
  };
  std::vector<Slot> slots_;
  AdamWOptions options_;
  void ensure_state(Slot& s);
};

}  // namespace flat::train
