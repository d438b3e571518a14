// The scores a model that ignores its input would also reach. A figure of
// flat_eval (or of the trainer's validation) counts only where it clears them:
//   mean-colour oracle: every view painted its own mean colour (an oracle:
//     it knows each view's colour);
//   dataset mean: every view predicted as the mean of the OTHER scenes of the
//     dataset at the same frame index (leave-one-out: the best "same output
//     for every scene" fitted without the scene itself);
//   swap: each scene's renders scored against another scene's ground truth
//     at the same frame index (the next scene of the dataset, cyclically). A
//     model that ignores its latents scores the same on its own scene and on
//     the swapped one; the gap own - swap is what the input is worth.
#pragma once
#include <cstdint>
#include <map>
#include <optional>
#include <string>
#include <vector>

#include <ATen/ATen.h>

namespace flat::eval {

// Sums of the ground-truth frames of a dataset's scenes by frame index, at one
// evaluation size, for the leave-one-out mean.
class FrameSums {
 public:
  void add(int64_t frame, const at::Tensor& image);  // image (3,H,W) in [0,1]
  void add(const FrameSums& other);                   // every frame of another set
  // The mean of the other scenes' frame `frame` (own excluded), or nothing when
  // no other scene has that frame at that size.
  std::optional<at::Tensor> leave_one_out(int64_t frame, const at::Tensor& own) const;
  bool empty() const { return sums_.empty(); }

 private:
  std::map<int64_t, std::pair<at::Tensor, int64_t>> sums_;  // frame -> (float64 sum, count)
};

// The scene each scene is swapped with: the next one, cyclically (i + 1) mod n;
// none when n < 2. A cyclic permutation, so a constant output's swap mean equals
// its own mean exactly.
std::optional<size_t> swap_partner(size_t index, size_t count);

// PSNR of painting each view (V,3,H,W) its own mean colour: (V).
at::Tensor mean_colour_psnr(const at::Tensor& target);

}  // namespace flat::eval
