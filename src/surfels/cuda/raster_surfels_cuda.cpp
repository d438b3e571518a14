// libtorch glue of the CUDA surfel rasterizer: allocation, the per-view loop
// and the launch checks. Per view: preprocess all surfels, sum their tile
// counts (one host wait: the pair count), bin their support boxes (the
// shared binning, flat/render/shared/tile_lists.h), composite. The forward keeps per view the sorted surfel indices,
// the tile ranges and the per-pixel state (final transmittance, last entry,
// distortion totals); the backward recomputes the screen data (one cheap
// kernel), replays every tile and chains the view's gradients to the inputs.
#include "surfels/cuda/raster_surfels_cuda.h"

#include <limits>

#include <ATen/cuda/CUDAContext.h>
#include <c10/cuda/CUDAGuard.h>

#include "flat/core/error.h"
#include "flat/render/shared/tile_lists.h"
#include "surfels/cuda/surfel_kernels.h"

namespace flat::surfels::cuda {

void check_launch(const char* what) {
  const cudaError_t err = cudaGetLastError();
  if (err != cudaSuccess) fail(std::string("rasterize_surfels (cuda): ") + what + " failed: " + cudaGetErrorString(err));
}

namespace {

constexpr int64_t kViewState = 5;  // sorted indices, ranges, t_final, last, distortion totals
constexpr int64_t kSurfelFloats = sizeof(PixelSurfel<float>) / sizeof(float);
static_assert(sizeof(PixelSurfel<float>) == 80, "PixelSurfel<float>: 19 floats and an index, 16-byte aligned");

void zero_async(const at::Tensor& t, cudaStream_t stream) {
  const cudaError_t err = t.numel() > 0 ? cudaMemsetAsync(t.data_ptr(), 0, t.nbytes(), stream) : cudaSuccess;
  if (err != cudaSuccess) fail(std::string("rasterize_surfels (cuda): memset failed: ") + cudaGetErrorString(err));
}

// One view's screen data: the records, support boxes, tile counts and depth
// keys of all N surfels (records and boxes valid where tile_counts > 0).
struct ScreenData {
  at::Tensor surfels, rects, tile_counts, depth_keys;
  ScreenData(const SurfelInputs& in, const ViewParams& vp, cudaStream_t stream) {
    const int64_t N = in.means.size(0);
    const auto f = in.means.options();
    surfels = at::empty({N, kSurfelFloats}, f);
    rects = at::empty({N, 4}, f.dtype(at::kInt));
    tile_counts = at::empty({N}, f.dtype(at::kInt));
    depth_keys = at::empty({N}, f.dtype(at::kInt));
    launch_preprocess(in.means.data_ptr<float>(), in.scales.data_ptr<float>(), in.rotations.data_ptr<float>(),
                      in.colors.data_ptr<float>(), in.opacities.data_ptr<float>(), N, vp, surfel_ptr(),
                      reinterpret_cast<SurfelRect*>(rects.data_ptr<int>()), tile_counts.data_ptr<int>(),
                      reinterpret_cast<uint32_t*>(depth_keys.data_ptr<int>()), stream);
    check_launch("preprocess");
  }
  PixelSurfel<float>* surfel_ptr() const { return reinterpret_cast<PixelSurfel<float>*>(surfels.data_ptr<float>()); }
};

// Bins one view (the shared binning of the support boxes): the sorted surfel
// indices and the tile ranges.
render::cuda::TileLists bin(const ScreenData& sd, const ViewParams& vp, int64_t N, cudaStream_t stream,
                            int64_t view) {
  // The pair count in 64 bits (one host wait a view). The kernels index the
  // pairs in int32 and step through a tile's list in rounds of kBlockSize.
  const int64_t pairs = N > 0 ? sd.tile_counts.sum(at::kLong).item<int64_t>() : 0;
  FLAT_CHECK(pairs <= std::numeric_limits<int32_t>::max() - kBlockSize,
             "rasterize_surfels (cuda): view " + std::to_string(view) + " needs " + std::to_string(pairs) +
                 " (surfel, tile) pairs, more than the ~2^31 the sort supports; render fewer or smaller surfels");
  render::cuda::RectFootprints fp;
  fp.depth_keys = reinterpret_cast<const uint32_t*>(sd.depth_keys.data_ptr<int>());
  fp.tile_counts = sd.tile_counts.data_ptr<int>();
  fp.rects = reinterpret_cast<const SurfelRect*>(sd.rects.data_ptr<int>());
  fp.n = N;
  return render::cuda::bin_rects(fp, pairs, kTileSize, vp.tiles_x, vp.tiles_y, sd.tile_counts.options(), stream,
                                 "rasterize_surfels");
}

void check_sizes(const SurfelInputs& in) {
  FLAT_CHECK(in.means.scalar_type() == at::kFloat, "rasterize_surfels (cuda): expected float32 tensors");
  FLAT_CHECK(in.means.size(0) < std::numeric_limits<int32_t>::max(),
             "rasterize_surfels (cuda): more surfels than the 2^31-1 the kernels index");
}

}  // namespace

SurfelOutputs forward(const SurfelInputs& in, bool for_backward, std::vector<at::Tensor>& views) {
  check_sizes(in);
  const c10::cuda::CUDAGuard guard(in.means.device());
  const cudaStream_t stream = at::cuda::getCurrentCUDAStream();
  const int64_t N = in.means.size(0), V = in.w2c.size(0), H = in.height, W = in.width, HW = H * W;
  const auto f = in.means.options();
  SurfelOutputs out = images_for(in);
  const at::Tensor max_bits = at::zeros({N}, f.dtype(at::kInt));
  views.clear();
  for (int64_t v = 0; v < V; ++v) {
    const ViewParams vp = render::splat_view(in, v);
    const ScreenData sd(in, vp, stream);
    const render::cuda::TileLists lists = bin(sd, vp, N, stream, v);
    const at::Tensor &sorted_values = lists.ids, &ranges = lists.ranges;
    const at::Tensor t_final = at::empty({H, W}, f), last = at::empty({H, W}, f.dtype(at::kInt));
    const at::Tensor dist = at::empty({3, H, W}, f);
    const ForwardImages img{out.rgb.data_ptr<float>() + v * 3 * HW,    out.alpha.data_ptr<float>() + v * HW,
                            out.depth.data_ptr<float>() + v * HW,      out.normal.data_ptr<float>() + v * 3 * HW,
                            out.median_depth.data_ptr<float>() + v * HW, out.distortion.data_ptr<float>() + v * HW,
                            t_final.data_ptr<float>(),                  last.data_ptr<int>(),
                            dist.data_ptr<float>()};
    launch_raster_forward(reinterpret_cast<const int2*>(ranges.data_ptr<int>()), sorted_values.data_ptr<int>(),
                          sd.surfel_ptr(), vp, img, reinterpret_cast<unsigned int*>(max_bits.data_ptr<int>()), stream);
    check_launch("forward rasterization");
    if (for_backward) views.insert(views.end(), {sorted_values, ranges, t_final, last, dist});
  }
  out.max_weight = max_bits.view(at::kFloat);  // non-negative floats: integer max == float max
  return out;
}

SurfelGrads backward(const SurfelInputs& in, const std::vector<at::Tensor>& views, const SurfelOutputGrads& grads) {
  check_sizes(in);
  const c10::cuda::CUDAGuard guard(in.means.device());
  const cudaStream_t stream = at::cuda::getCurrentCUDAStream();
  const int64_t N = in.means.size(0), V = in.w2c.size(0), HW = in.height * in.width;
  FLAT_CHECK((int64_t)views.size() == kViewState * V,
             "rasterize_surfels (cuda): backward state does not match the views");
  SurfelGrads g = SurfelGrads::zeros_for(in);
  if (N == 0) return g;
  const at::Tensor surfel_grads = at::empty({N, kSurfelGradStride}, in.means.options());
  for (int64_t v = 0; v < V; ++v) {
    auto state = [&](int i) -> const at::Tensor& { return views[kViewState * v + i]; };
    if (state(0).numel() == 0) continue;  // nothing blended in this view
    const ViewParams vp = render::splat_view(in, v);
    const ScreenData sd(in, vp, stream);  // bit-identical to the forward's
    zero_async(surfel_grads, stream);
    const BackwardImages img{grads.rgb.data_ptr<float>() + v * 3 * HW,   grads.alpha.data_ptr<float>() + v * HW,
                             grads.depth.data_ptr<float>() + v * HW,     grads.normal.data_ptr<float>() + v * 3 * HW,
                             grads.distortion.data_ptr<float>() + v * HW, state(2).data_ptr<float>(),
                             state(3).data_ptr<int>(),                    state(4).data_ptr<float>()};
    launch_raster_backward(reinterpret_cast<const int2*>(state(1).data_ptr<int>()), state(0).data_ptr<int>(),
                           sd.surfel_ptr(), vp, img, surfel_grads.data_ptr<float>(), stream);
    check_launch("backward rasterization");
    launch_chain(in.means.data_ptr<float>(), in.scales.data_ptr<float>(), in.rotations.data_ptr<float>(), N, vp.cam,
                 sd.tile_counts.data_ptr<int>(), surfel_grads.data_ptr<float>(), g.means.data_ptr<float>(),
                 g.scales.data_ptr<float>(), g.rotations.data_ptr<float>(), g.colors.data_ptr<float>(),
                 g.opacities.data_ptr<float>(), stream);
    check_launch("preprocess backward");
  }
  return g;
}

}  // namespace flat::surfels::cuda
