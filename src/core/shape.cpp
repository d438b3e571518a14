#include "flat/core/shape.h"

#include <sstream>

#include "flat/core/error.h"

namespace flat {

std::string shape_str(at::IntArrayRef sizes) {
  std::ostringstream s;
  s << "(";
  for (size_t i = 0; i < sizes.size(); ++i) s << (i ? "," : "") << sizes[i];
  s << ")";
  return s.str();
}

void check_shape(const at::Tensor& t, const std::vector<int64_t>& expected, const std::string& what,
                 const std::string& layout) {
  bool ok = t.defined() && t.dim() == static_cast<int64_t>(expected.size());
  for (size_t i = 0; ok && i < expected.size(); ++i) ok = expected[i] < 0 || t.size(i) == expected[i];
  if (!ok) fail(what + ": expected shape " + layout + ", got " + shape_str(t));
}

void check_finite(const at::Tensor& t, const std::string& what) {
  if (!t.defined() || !t.is_floating_point() || t.numel() == 0) return;
  if (!at::isfinite(t).all().item<bool>()) {
    auto bad = (~at::isfinite(t)).sum().item<int64_t>();
    fail(what + ": " + std::to_string(bad) + " non-finite value(s) (NaN or Inf) in tensor of shape " + shape_str(t));
  }
}

bool parse_size(const std::string& text, int64_t& height, int64_t& width) {
  const auto x = text.find('x');
  if (x == std::string::npos || x == 0 || x + 1 >= text.size()) return false;
  for (size_t i = 0; i < text.size(); ++i)
    if (i != x && (text[i] < '0' || text[i] > '9')) return false;
  if (x > 7 || text.size() - x - 1 > 7) return false;  // no overflow, and no absurd sizes
  height = std::stoll(text.substr(0, x));
  width = std::stoll(text.substr(x + 1));
  return height > 0 && width > 0;
}

}  // namespace flat
