// AdamW (Loshchilov & Hutter) with its state held in plain named tensors, so a
// checkpoint stores and restores it exactly (and the 8-bit variant can share
// the interface). Paper, Implementation Details: AdamW, lr 1e-4.
//
//   p <- p - lr * wd * p
//   m <- b1 m + (1 - b1) g ;  v <- b2 v + (1 - b2) g^2
//   p <- p - lr * (m / (1 - b1^t)) / (sqrt(v / (1 - b2^t)) + eps)
//
// With `fused` (the default) the update is ATen's fused multi-tensor kernel
// (_fused_adamw_, as PyTorch's `fused=True`) on CUDA and on the CPU alike, so
// the CPU tests run the path the GPU runs; otherwise, and for tensors the
// kernel does not take, the loop in step(), op for op as torch.optim.AdamW's
// single-tensor path. The fused kernel does not bump version counters; step()
// does, so caches keyed on a weight's version see every step.
//
// With state_bits = 8 (the paper's stage 4: 8-bit Adam) m and v of every
// parameter with at least min_8bit_numel values are held block-wise quantised
// (blockwise_quantisation.h: uint8 codes + one float per 256 values, about a
// quarter of fp32 state); each step dequantises them, updates as above in
// fp32, and quantises them again. Smaller tensors (biases, norms) keep fp32
// state, as bitsandbytes does. On CUDA (fused_8bit, a build with FLAT_WITH_CUDA,
// contiguous fp32 or bf16 parameters and gradients) that is one fused kernel
// per tensor updating the state in place (src/optim/cuda/adamw8bit_step.cu);
// otherwise, and with fused_8bit = false, the ATen ops of update_8bit: the CPU
// path and the reference the kernel is tested against (same arithmetic, op
// for op).
#pragma once
#include <cstdint>
#include <string>
#include <utility>
#include <vector>

#include <ATen/ATen.h>

#include "flat/core/tensor_io.h"
#include "flat/optim/blockwise_quantisation.h"

namespace flat::optim {

struct AdamWOptions {
  double beta1 = 0.9, beta2 = 0.999, eps = 1e-8, weight_decay = 0.01;
  bool fused = true;       // fp32-state tensors: ATen's fused multi-tensor kernel (CUDA and CPU); false: op by op
  bool fused_8bit = true;  // CUDA, 8-bit-state tensors: our fused kernel; false: the ATen reference ops
  int state_bits = 32;             // 32 | 8
  int64_t min_8bit_numel = 4096;   // smaller tensors keep fp32 state
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

  // "exp_avg.<name>", "exp_avg_sq.<name>", "step.<name>" (CPU copies); 8-bit
  // state as "exp_avg.q8.<name>" / "exp_avg.absmax.<name>" (and exp_avg_sq).
  // A parameter not yet updated has no entries. load_state converts between
  // the two forms, so a run may switch state_bits at a resume.
  TensorMap state() const;
  // Restores state() output; throws flat::Error naming `label` and the tensor
  // on an unknown name or a shape that does not match the parameter.
  void load_state(const TensorMap& state, const std::string& label);
  // Bytes of optimiser state held now.
  int64_t state_bytes() const;

  // Whether this build has the fused 8-bit CUDA kernel (FLAT_WITH_CUDA), and
  // how many tensor updates it has done here (tests and benchmarks: that the
  // fused path was taken).
  static bool fused_8bit_available();
  int64_t fused_8bit_updates() const { return fused_8bit_updates_; }

 private:
  struct Slot {
    std::string name;
    at::Tensor param, exp_avg, exp_avg_sq, step;  // step: float32 scalar on the param's device
    QuantisedTensor exp_avg_q8, exp_avg_sq_q8;    // 8-bit state (exp_avg, exp_avg_sq undefined then)
    double steps = 0;  // step's value, kept on the host: the fused 8-bit step reads no device scalar
    bool has_state() const { return step.defined(); }
  };
  bool quantised(const Slot& s) const;
  void update_8bit(Slot& s, const at::Tensor& grad, double lr);
  bool fused_8bit(const Slot& s, const at::Tensor& grad) const;
  void update_8bit_fused(Slot& s, const at::Tensor& grad, double lr);
  std::vector<Slot> slots_;
  AdamWOptions options_;
  int64_t fused_8bit_updates_ = 0;
  void ensure_state(Slot& s);
};

}  // namespace flat::optim
