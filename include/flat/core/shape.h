// Shape formatting and checks for error messages: "(2,3,16,16)".
#pragma once
#include <string>
#include <vector>

#include <ATen/ATen.h>

namespace flat {

std::string shape_str(at::IntArrayRef sizes);
inline std::string shape_str(const at::Tensor& t) { return t.defined() ? shape_str(t.sizes()) : "(undefined)"; }

// Throws flat::Error "<what>: expected shape (V,3,H,W) with ..., got (..)" unless
// `t` has exactly `dims` dimensions and every non-negative entry of `expected`
// matches (-1 = any). `layout` is the human-readable form, e.g. "(V,3,H,W)".
void check_shape(const at::Tensor& t, const std::vector<int64_t>& expected, const std::string& what,
                 const std::string& layout);

// Throws flat::Error naming `what` if `t` holds NaN or Inf.
void check_finite(const at::Tensor& t, const std::string& what);

// An image size "HxW" (e.g. "176x320", both > 0) -> height, width; false when malformed.
bool parse_size(const std::string& text, int64_t& height, int64_t& width);

}  // namespace flat
