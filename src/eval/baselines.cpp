#include "flat/eval/baselines.h"

#include "flat/core/error.h"
#include "flat/core/shape.h"
#include "flat/eval/image_metrics.h"

namespace flat::eval {

void FrameSums::add(int64_t frame, const at::Tensor& image) {
  FLAT_CHECK(image.dim() == 3 && image.size(0) == 3, "FrameSums: expected an image (3,H,W), got " + shape_str(image));
  auto x = image.to(at::kCPU, at::kDouble);
  auto it = sums_.find(frame);
  if (it == sums_.end()) {
    sums_[frame] = {x.clone(), 1};
    return;
  }
  FLAT_CHECK(it->second.first.sizes() == x.sizes(), "FrameSums: frame " + std::to_string(frame) + " of size " +
                                                        shape_str(x) + " differs from the dataset's " +
                                                        shape_str(it->second.first));
  it->second.first += x;
  it->second.second += 1;
}

void FrameSums::add(const FrameSums& other) {
  for (const auto& [frame, sum] : other.sums_) {
    auto it = sums_.find(frame);
    if (it == sums_.end()) {
      sums_[frame] = {sum.first.clone(), sum.second};
      continue;
    }
    FLAT_CHECK(it->second.first.sizes() == sum.first.sizes(),
               "FrameSums: frame " + std::to_string(frame) + " of size " + shape_str(sum.first) +
                   " differs from the dataset's " + shape_str(it->second.first));
    it->second.first += sum.first;
    it->second.second += sum.second;
  }
}

std::optional<at::Tensor> FrameSums::leave_one_out(int64_t frame, const at::Tensor& own) const {
  auto it = sums_.find(frame);
  if (it == sums_.end() || it->second.second < 2 || it->second.first.sizes() != own.sizes()) return std::nullopt;
  return ((it->second.first - own.to(at::kCPU, at::kDouble)) / double(it->second.second - 1)).to(at::kFloat);
}

std::optional<size_t> swap_partner(size_t index, size_t count) {
  if (count < 2) return std::nullopt;
  return (index + 1) % count;
}

at::Tensor mean_colour_psnr(const at::Tensor& target) {
  return psnr(target.mean({2, 3}, true).expand_as(target), target);
}

}  // namespace flat::eval
