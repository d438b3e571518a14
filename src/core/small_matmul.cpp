// Tiny batched matrix products as broadcast multiply and sum (small_matmul.h).
#include "flat/core/small_matmul.h"

#include "flat/core/error.h"
#include "flat/core/shape.h"

namespace flat {

at::Tensor small_matmul(const at::Tensor& a, const at::Tensor& b) {
  FLAT_CHECK(a.dim() >= 2 && b.dim() >= 2 && a.size(-1) == b.size(-2),
             "small_matmul: cannot multiply " + shape_str(a) + " by " + shape_str(b));
  FLAT_CHECK(a.scalar_type() == b.scalar_type(), "small_matmul: operands of different dtypes");
  // (...,m,k,1) * (...,1,k,n) -> (...,m,k,n), summed over k.
  return (a.unsqueeze(-1) * b.unsqueeze(-3)).sum(-2);
}

}  // namespace flat
