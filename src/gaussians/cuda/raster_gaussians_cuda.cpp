// libtorch glue of the CUDA Gaussian rasterizer: allocation, the loop over
// chunks of views and the launch checks. Per chunk (chunk_views(): up to 16
// views, at most 2^24 (view, Gaussian) elements): preprocess every Gaussian in
// every view of the chunk (screen data, pixel boxes, depth keys, tile
// counts), wait for the chunk's pair count (the one host sync a chunk; the
// input value checks ride on the first), bin the boxes and tile masks of all
// its views at once (the shared binning, flat/render/shared/tile_lists.h),
// composite all its views in one launch. The backward recomputes the screen
// data per chunk (one cheap kernel) instead of keeping it.
#include "gaussians/cuda/raster_gaussians_cuda.h"

#include <ATen/cuda/CUDAContext.h>
#include <c10/cuda/CUDAGuard.h>

#include <algorithm>
#include <limits>
#include <vector>

#include "flat/core/error.h"
#include "flat/render/shared/tile_lists.h"
#include "gaussians/cuda/gaussian_kernels.h"

namespace flat::gaussians::cuda {

void check_launch(const char* what) {
  const cudaError_t err = cudaGetLastError();
  if (err != cudaSuccess)
    fail(std::string("rasterize_gaussians (cuda): ") + what + " failed: " + cudaGetErrorString(err));
}

namespace {

constexpr int64_t kScreenFloats = sizeof(ScreenGaussian<float>) / sizeof(float);
static_assert(sizeof(ScreenGaussian<float>) == 12 * sizeof(float), "ScreenGaussian layout (three float4)");
static_assert(sizeof(ScreenGrad<float>) == kScreenGradSize * sizeof(float), "ScreenGrad layout");
static_assert(sizeof(PixelBox) == 4 * sizeof(int), "PixelBox layout");
// Per chunk, kept for the backward: sorted ids, tile ranges, final T, last entry.
constexpr int64_t kChunkState = 4;

void check_dtype(const GaussianInputs& in) {
  FLAT_CHECK(in.means.scalar_type() == at::kFloat, "rasterize_gaussians (cuda): expected float32 tensors");
  FLAT_CHECK(in.means.size(0) < std::numeric_limits<int32_t>::max(),
             "rasterize_gaussians (cuda): at most 2^31-1 Gaussians, got " + std::to_string(in.means.size(0)));
}

uint32_t* u32(const at::Tensor& t) { return reinterpret_cast<uint32_t*>(t.data_ptr<int>()); }

// One chunk's preprocessing state over its views x N elements (allocated for
// the largest chunk, reused by the others).
struct Preprocessed {
  at::Tensor screen, boxes, depth_keys, masks, counts, total;
  explicit Preprocessed(int64_t elements, const at::TensorOptions& f)
      : screen(at::empty({elements * kScreenFloats}, f)),
        boxes(at::empty({elements * 4}, f.dtype(at::kInt))),
        depth_keys(at::empty({elements}, f.dtype(at::kInt))),
        masks(at::empty({elements}, f.dtype(at::kInt))),
        counts(at::empty({elements}, f.dtype(at::kInt))),
        total(at::empty({1}, f.dtype(at::kLong))) {}
  void run(const GaussianInputs& in, const ViewChunk& chunk, cudaStream_t stream) {
    launch_preprocess(in.means.data_ptr<float>(), in.scales.data_ptr<float>(), in.rotations.data_ptr<float>(),
                      in.colors.data_ptr<float>(), in.opacities.data_ptr<float>(), chunk, screen_ptr(), box_ptr(),
                      key_ptr(), u32(masks), counts.data_ptr<int>(),
                      reinterpret_cast<unsigned long long*>(total.data_ptr<int64_t>()), stream);
    check_launch("preprocessing");
  }
  ScreenGaussian<float>* screen_ptr() { return reinterpret_cast<ScreenGaussian<float>*>(screen.data_ptr<float>()); }
  PixelBox* box_ptr() { return reinterpret_cast<PixelBox*>(boxes.data_ptr<int>()); }
  uint32_t* key_ptr() { return reinterpret_cast<uint32_t*>(depth_keys.data_ptr<int>()); }
};

}  // namespace

GaussianOutputs forward(const GaussianInputs& in, bool for_backward, std::vector<at::Tensor>& views) {
  check_dtype(in);
  const c10::cuda::CUDAGuard guard(in.means.device());
  const cudaStream_t stream = at::cuda::getCurrentCUDAStream().stream();
  const int64_t V = in.w2c.size(0), H = in.height, W = in.width, HW = H * W, N = in.means.size(0);
  const auto f = in.means.options();
  GaussianOutputs out = images_for(in);
  at::Tensor max_bits = at::zeros({N}, f.dtype(at::kInt));
  const int per_chunk = chunk_views(V, N);
  Preprocessed pre(per_chunk * N, f);
  at::Tensor host_total = at::zeros({1}, at::TensorOptions().dtype(at::kLong).pinned_memory(true));
  views.clear();
  for (int64_t v0 = 0; v0 < V; v0 += per_chunk) {
    const int count = int(std::min<int64_t>(per_chunk, V - v0));
    const ViewChunk chunk = render::view_chunk(in, v0, count);
    const ViewParams& vp = chunk.v[0];
    pre.run(in, chunk, stream);
    FLAT_CHECK(cudaMemcpyAsync(host_total.data_ptr(), pre.total.data_ptr(), sizeof(int64_t), cudaMemcpyDeviceToHost,
                               stream) == cudaSuccess,
               "rasterize_gaussians (cuda): copying the pair count to the host failed");
    FLAT_CHECK(cudaStreamSynchronize(stream) == cudaSuccess, "rasterize_gaussians (cuda): preprocessing failed");
    // The statistics' copy was enqueued before: now on the host.
    if (v0 == 0) render::check_splat_values(in, "rasterize_gaussians");
    const int64_t pairs = host_total.data_ptr<int64_t>()[0];
    // The kernels index the pairs in int32 and step through a tile's list in batches of kBlockSize.
    FLAT_CHECK(pairs <= std::numeric_limits<int32_t>::max() - kBlockSize,
               "rasterize_gaussians (cuda): " + std::to_string(pairs) + " (Gaussian, tile) pairs in views " +
                   std::to_string(v0) + ".." + std::to_string(v0 + count - 1) +
                   " (one chunk), more than the ~2^31 the sort supports; render fewer views a call, or fewer or "
                   "smaller Gaussians");
    render::cuda::RectFootprints fp;
    fp.depth_keys = pre.key_ptr();
    fp.tile_counts = pre.counts.data_ptr<int>();
    fp.rects = pre.box_ptr();
    fp.masks = u32(pre.masks);
    fp.n = count * N;
    fp.per_view = N;
    const render::cuda::TileLists lists = render::cuda::bin_rects(fp, pairs, kTileSize, vp.tiles_x, vp.tiles_y, count,
                                                                  f, stream, "rasterize_gaussians");
    at::Tensor t_final, last;
    if (for_backward) {
      t_final = at::empty({count, H, W}, f);
      last = at::empty({count, H, W}, f.dtype(at::kInt));
    }
    ForwardImages img{out.rgb.data_ptr<float>() + v0 * 3 * HW,
                      out.alpha.data_ptr<float>() + v0 * HW,
                      out.depth.data_ptr<float>() + v0 * HW,
                      out.median_depth.data_ptr<float>() + v0 * HW,
                      for_backward ? t_final.data_ptr<float>() : nullptr,
                      for_backward ? last.data_ptr<int>() : nullptr};
    launch_raster_forward(reinterpret_cast<const int2*>(lists.ranges.data_ptr<int>()), lists.ids.data_ptr<int>(),
                          pre.screen_ptr(), chunk, img, reinterpret_cast<unsigned int*>(max_bits.data_ptr<int>()),
                          stream);
    check_launch("forward compositing");
    if (for_backward) views.insert(views.end(), {lists.ids, lists.ranges, t_final, last});
  }
  if (V == 0) {
    FLAT_CHECK(cudaStreamSynchronize(stream) == cudaSuccess, "rasterize_gaussians (cuda): value checks failed");
    render::check_splat_values(in, "rasterize_gaussians");
  }
  out.max_weight = max_bits.view(at::kFloat);  // non-negative floats, stored as their bits
  return out;
}

GaussianGrads backward(const GaussianInputs& in, const std::vector<at::Tensor>& views,
                       const GaussianOutputGrads& grads) {
  check_dtype(in);
  const c10::cuda::CUDAGuard guard(in.means.device());
  const cudaStream_t stream = at::cuda::getCurrentCUDAStream().stream();
  const int64_t V = in.w2c.size(0), HW = in.height * in.width, N = in.means.size(0);
  const int per_chunk = chunk_views(V, N);
  FLAT_CHECK((int64_t)views.size() == kChunkState * ((V + per_chunk - 1) / per_chunk),
             "rasterize_gaussians (cuda): backward state does not match the views");
  const auto f = in.means.options();
  GaussianGrads g = GaussianGrads::zeros_for(in);
  // Zeroed once; the chain zeroes again every row it reads.
  at::Tensor screen_grads = at::zeros({per_chunk * N * kGradStride}, f);
  Preprocessed pre(per_chunk * N, f);
  for (int64_t v0 = 0, c = 0; v0 < V; v0 += per_chunk, ++c) {
    const int count = int(std::min<int64_t>(per_chunk, V - v0));
    const ViewChunk chunk = render::view_chunk(in, v0, count);
    pre.run(in, chunk, stream);  // the forward's screen data, recomputed bit for bit
    const at::Tensor& ids = views[kChunkState * c];
    const at::Tensor& ranges = views[kChunkState * c + 1];
    BackwardImages img{grads.rgb.data_ptr<float>() + v0 * 3 * HW, grads.alpha.data_ptr<float>() + v0 * HW,
                       grads.depth.data_ptr<float>() + v0 * HW, views[kChunkState * c + 2].data_ptr<float>(),
                       views[kChunkState * c + 3].data_ptr<int>()};
    launch_raster_backward(reinterpret_cast<const int2*>(ranges.data_ptr<int>()), ids.data_ptr<int>(), pre.screen_ptr(),
                           chunk, img, screen_grads.data_ptr<float>(), stream);
    check_launch("backward compositing");
    launch_chain(in.means.data_ptr<float>(), in.scales.data_ptr<float>(), in.rotations.data_ptr<float>(), chunk,
                 pre.counts.data_ptr<int>(), screen_grads.data_ptr<float>(), g.means.data_ptr<float>(),
                 g.scales.data_ptr<float>(), g.rotations.data_ptr<float>(), g.colors.data_ptr<float>(),
                 g.opacities.data_ptr<float>(), stream);
    check_launch("chain rule");
  }
  return g;
}

}  // namespace flat::gaussians::cuda
