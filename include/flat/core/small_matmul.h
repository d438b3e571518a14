// Products of batches of tiny matrices (the 2x2, 2x3 and 3x3 per triangle,
// per ray or per pixel of the geometry), shared by core, camera and
// primitives (public so that they may include it); not a general matmul.
//
// Why not at::matmul: on CUDA it sends them to cuBLAS batched GEMM, which
// splits millions of 3x3 products into hundreds of launches of tensor-core
// kernels (~40 ms forward, ~25 ms backward at 2.8 M triangles), and under
// autocast it casts them to bf16 (~3 significant digits: vertices off by ~1e-2
// relative). A broadcast elementwise product and a sum is a few memory-bound
// kernels, and autocast leaves both ops in the inputs' precision. Same maths;
// only the summation order may differ.
#pragma once
#include <ATen/ATen.h>

namespace flat {

// (...,m,k) x (...,k,n) -> (...,m,n), the batch dimensions broadcast as in
// at::matmul (both operands at least 2-D, same dtype). For matrix-vector
// products pass v.unsqueeze(-1) and squeeze(-1) the result. Meant for small
// k, m, n: it materialises (...,m,k,n).
at::Tensor small_matmul(const at::Tensor& a, const at::Tensor& b);

}  // namespace flat
