#include "flat/optim/blockwise_quantisation.h"

#include <algorithm>
#include <cmath>
#include <map>
#include <mutex>
#include <vector>

#include "flat/core/error.h"

namespace flat::optim {

at::Tensor dynamic_map(bool is_signed) {
  // 8 bits: one sign bit (signed maps), 7 exponent steps e = 0..6 of scale
  // 10^(e-6), each holding the midpoints of a linear grid over [0.1, 1]
  // (2^e midpoints when signed, 2^(e+1) when not), then 0 and 1.
  std::vector<double> v;
  for (int e = 0; e < 7; ++e) {
    const int64_t items = is_signed ? (int64_t(1) << e) + 1 : (int64_t(1) << (e + 1)) + 1;
    const double scale = std::pow(10.0, double(e - 6));
    for (int64_t k = 0; k + 1 < items; ++k) {
      const double a = 0.1 + 0.9 * double(k) / double(items - 1), b = 0.1 + 0.9 * double(k + 1) / double(items - 1);
      v.push_back(scale * 0.5 * (a + b));
      if (is_signed) v.push_back(-scale * 0.5 * (a + b));
    }
  }
  v.push_back(0.0);
  v.push_back(1.0);
  FLAT_CHECK(v.size() == 256, "dynamic_map: built " + std::to_string(v.size()) + " values, expected 256");
  std::sort(v.begin(), v.end());
  return at::tensor(v, at::kDouble).to(at::kFloat);
}

const DynamicMapTables& dynamic_map_tables(bool is_signed, const at::Device& device) {
  static std::mutex mutex;
  static std::map<std::pair<bool, std::string>, DynamicMapTables> cache;
  std::lock_guard<std::mutex> lock(mutex);
  auto& m = cache[{is_signed, device.str()}];
  if (!m.values.defined()) {
    auto v = dynamic_map(is_signed);
    m.values = v.to(device);
    m.midpoints = ((v.slice(0, 0, 255) + v.slice(0, 1, 256)) * 0.5).to(device);
  }
  return m;
}

QuantisedTensor quantise_blockwise(const at::Tensor& x, bool is_signed) {
  at::NoGradGuard no_grad;
  QuantisedTensor q;
  q.numel = x.numel();
  q.is_signed = is_signed;
  const int64_t blocks = (q.numel + kQuantBlock - 1) / kQuantBlock;
  auto flat = x.detach().reshape({-1}).to(at::kFloat);
  flat = at::constant_pad_nd(flat, {0, blocks * kQuantBlock - q.numel}, 0.0).view({blocks, kQuantBlock});
  q.absmax = flat.abs().amax(1);
  auto safe = at::where(q.absmax > 0, q.absmax, at::ones_like(q.absmax)).unsqueeze(1);
  auto normalised = (flat / safe).clamp(is_signed ? -1.0 : 0.0, 1.0);
  // Index of the nearest map value: the number of midpoints below the value.
  const auto& m = dynamic_map_tables(is_signed, x.device());
  q.codes = at::bucketize(normalised, m.midpoints).to(at::kByte).reshape({-1});
  return q;
}

at::Tensor dequantise_blockwise(const QuantisedTensor& q, at::IntArrayRef shape) {
  FLAT_CHECK(q.codes.defined(), "dequantise_blockwise: empty state");
  const auto& m = dynamic_map_tables(q.is_signed, q.codes.device());
  auto values = m.values.index_select(0, q.codes.to(at::kLong)).view({-1, kQuantBlock}) * q.absmax.unsqueeze(1);
  return values.reshape({-1}).slice(0, 0, q.numel).view(shape);
}

}  // namespace flat::optim
