// Block-wise dynamic 8-bit quantisation of optimiser state (Dettmers et al.
// 2021, "8-bit Optimizers via Block-wise Quantization"; the paper's stage 4
// uses 8-bit Adam). A tensor is cut into blocks of 256 values; each block
// keeps one float absmax and one uint8 code per value; a code indexes a
// 256-entry "dynamic" map of values in [-1, 1] (signed, for Adam's first
// moment) or [0, 1] (unsigned, for the second) whose resolution follows the
// magnitude: an exponent (powers of ten) and a linear fraction.
//
//   quantise:   code = nearest map entry to x / absmax(block)
//   dequantise: x = map[code] * absmax(block)
//
// Written with ATen ops, so the same code runs on the CPU and on CUDA.
#pragma once
#include <cstdint>

#include <ATen/ATen.h>

namespace flat::optim {

inline constexpr int64_t kQuantBlock = 256;

// The 256 sorted values of the dynamic map (float32, CPU): 7 exponent steps
// (1e-6 .. 1) of linearly spaced fractions, plus 0 and 1; signed maps hold
// the negatives too.
at::Tensor dynamic_map(bool is_signed);

// The map and the 255 midpoints between its neighbours (the quantiser's
// decision boundaries: a value gets the code of the number of midpoints below
// it), float32 on `device`, built once per device. The fused CUDA step
// (src/train/cuda/adamw8bit_step.cu) reads these same tensors.
struct DynamicMapTables {
  at::Tensor values, midpoints;  // (256), (255)
};
const DynamicMapTables& dynamic_map_tables(bool is_signed, const at::Device& device);

struct QuantisedTensor {
  at::Tensor codes;   // (blocks * 256) uint8
  at::Tensor absmax;  // (blocks) float32
  int64_t numel = 0;
  bool is_signed = true;
  int64_t nbytes() const { return codes.defined() ? int64_t(codes.nbytes() + absmax.nbytes()) : 0; }
};

// x: any shape, float; the result lives on x's device.
QuantisedTensor quantise_blockwise(const at::Tensor& x, bool is_signed);
// Back to float32 with the given shape (numel must match).
at::Tensor dequantise_blockwise(const QuantisedTensor& q, at::IntArrayRef shape);

}  // namespace flat::optim
