// libtorch glue of the CUDA surfel rasterizer: allocation, the loop over
// chunks of views and the launch checks. Per chunk (chunk_views(): up to 16
// views, at most 2^24 (view, surfel) elements): preprocess every surfel in
// every view of the chunk, sum their tile counts (one host wait a chunk: the
// pair count), bin the support boxes of all its views at once (the shared
// binning, flat/render/shared/tile_lists.h), composite all its views in one
// launch. The forward keeps per chunk the sorted element indices, the tile
// ranges and the per-pixel state (final transmittance, last entry,
// distortion totals); the backward recomputes the screen data (one cheap
// kernel), replays every tile and chains the chunk's gradients to the inputs.
#include "surfels/cuda/raster_surfels_cuda.h"

#include <algorithm>
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

constexpr int64_t kChunkState = 5;  // sorted elements, ranges, t_final, last, distortion totals
constexpr int64_t kSurfelFloats = sizeof(PixelSurfel<float>) / sizeof(float);
static_assert(sizeof(PixelSurfel<float>) == 80, "PixelSurfel<float>: 19 floats and an index, 16-byte aligned");

void zero_async(const at::Tensor& t, cudaStream_t stream) {
  const cudaError_t err = t.numel() > 0 ? cudaMemsetAsync(t.data_ptr(), 0, t.nbytes(), stream) : cudaSuccess;
  if (err != cudaSuccess) fail(std::string("rasterize_surfels (cuda): memset failed: ") + cudaGetErrorString(err));
}

// One chunk's screen data: the records, support boxes, tile counts and depth
// keys of its views x N elements (records and boxes valid where tile_counts > 0).
struct ScreenData {
  at::Tensor surfels, rects, tile_counts, depth_keys;
  ScreenData(const SurfelInputs& in, const ViewChunk& chunk, cudaStream_t stream) {
    const int64_t E = chunk.views * chunk.per_view;
    const auto f = in.means.options();
    surfels = at::empty({E, kSurfelFloats}, f);
    rects = at::empty({E, 4}, f.dtype(at::kInt));
    tile_counts = at::empty({E}, f.dtype(at::kInt));
    depth_keys = at::empty({E}, f.dtype(at::kInt));
    launch_preprocess(in.means.data_ptr<float>(), in.scales.data_ptr<float>(), in.rotations.data_ptr<float>(),
                      in.colors.data_ptr<float>(), in.opacities.data_ptr<float>(), chunk, surfel_ptr(),
                      reinterpret_cast<SurfelRect*>(rects.data_ptr<int>()), tile_counts.data_ptr<int>(),
                      reinterpret_cast<uint32_t*>(depth_keys.data_ptr<int>()), stream);
    check_launch("preprocess");
  }
  PixelSurfel<float>* surfel_ptr() const { return reinterpret_cast<PixelSurfel<float>*>(surfels.data_ptr<float>()); }
};

// Bins one chunk (the shared binning of the support boxes of all its views):
// the sorted element indices and the tile ranges.
render::cuda::TileLists bin(const ScreenData& sd, const ViewChunk& chunk, cudaStream_t stream, int64_t first_view) {
  // The pair count in 64 bits (one host wait a chunk). The kernels index the
  // pairs in int32 and step through a tile's list in rounds of kBlockSize.
  const int64_t E = chunk.views * chunk.per_view;
  const int64_t pairs = E > 0 ? sd.tile_counts.sum(at::kLong).item<int64_t>() : 0;
  FLAT_CHECK(pairs <= std::numeric_limits<int32_t>::max() - kBlockSize,
             "rasterize_surfels (cuda): views " + std::to_string(first_view) + ".." +
                 std::to_string(first_view + chunk.views - 1) + " need " + std::to_string(pairs) +
                 " (surfel, tile) pairs (one chunk), more than the ~2^31 the sort supports; render fewer views a call, or "
                 "fewer or smaller surfels");
  render::cuda::RectFootprints fp;
  fp.depth_keys = reinterpret_cast<const uint32_t*>(sd.depth_keys.data_ptr<int>());
  fp.tile_counts = sd.tile_counts.data_ptr<int>();
  fp.rects = reinterpret_cast<const SurfelRect*>(sd.rects.data_ptr<int>());
  fp.n = E;
  fp.per_view = chunk.per_view;
  return render::cuda::bin_rects(fp, pairs, kTileSize, chunk.v[0].tiles_x, chunk.v[0].tiles_y, chunk.views,
                                 sd.tile_counts.options(), stream, "rasterize_surfels");
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
  const int per_chunk = chunk_views(V, N);
  views.clear();
  for (int64_t v0 = 0; v0 < V; v0 += per_chunk) {
    const int count = int(std::min<int64_t>(per_chunk, V - v0));
    const ViewChunk chunk = render::view_chunk(in, v0, count);
    const ScreenData sd(in, chunk, stream);
    const render::cuda::TileLists lists = bin(sd, chunk, stream, v0);
    const at::Tensor &sorted_values = lists.ids, &ranges = lists.ranges;
    const at::Tensor t_final = at::empty({count, H, W}, f), last = at::empty({count, H, W}, f.dtype(at::kInt));
    const at::Tensor dist = at::empty({count, 3, H, W}, f);
    const ForwardImages img{out.rgb.data_ptr<float>() + v0 * 3 * HW,    out.alpha.data_ptr<float>() + v0 * HW,
                            out.depth.data_ptr<float>() + v0 * HW,      out.normal.data_ptr<float>() + v0 * 3 * HW,
                            out.median_depth.data_ptr<float>() + v0 * HW, out.distortion.data_ptr<float>() + v0 * HW,
                            t_final.data_ptr<float>(),                   last.data_ptr<int>(),
                            dist.data_ptr<float>()};
    launch_raster_forward(reinterpret_cast<const int2*>(ranges.data_ptr<int>()), sorted_values.data_ptr<int>(),
                          sd.surfel_ptr(), chunk, img, reinterpret_cast<unsigned int*>(max_bits.data_ptr<int>()),
                          stream);
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
  const int per_chunk = chunk_views(V, N);
  FLAT_CHECK((int64_t)views.size() == kChunkState * ((V + per_chunk - 1) / per_chunk),
             "rasterize_surfels (cuda): backward state does not match the views");
  SurfelGrads g = SurfelGrads::zeros_for(in);
  if (N == 0) return g;
  const at::Tensor surfel_grads = at::empty({per_chunk * N, kSurfelGradStride}, in.means.options());
  float* const rows = surfel_grads.data_ptr<float>();  // one SurfelGrad row an element of the chunk
  for (int64_t v0 = 0, c = 0; v0 < V; v0 += per_chunk, ++c) {
    auto state = [&](int i) -> const at::Tensor& { return views[kChunkState * c + i]; };
    if (state(0).numel() == 0) continue;  // nothing blended in this chunk
    const int count = int(std::min<int64_t>(per_chunk, V - v0));
    const ViewChunk chunk = render::view_chunk(in, v0, count);
    const ScreenData sd(in, chunk, stream);  // bit-identical to the forward's
    zero_async(surfel_grads, stream);
    const BackwardImages img{grads.rgb.data_ptr<float>() + v0 * 3 * HW,   grads.alpha.data_ptr<float>() + v0 * HW,
                             grads.depth.data_ptr<float>() + v0 * HW,     grads.normal.data_ptr<float>() + v0 * 3 * HW,
                             grads.distortion.data_ptr<float>() + v0 * HW, state(2).data_ptr<float>(),
                             state(3).data_ptr<int>(),                     state(4).data_ptr<float>()};
    launch_raster_backward(reinterpret_cast<const int2*>(state(1).data_ptr<int>()), state(0).data_ptr<int>(),
                           sd.surfel_ptr(), chunk, img, rows, stream);
    check_launch("backward rasterization");
    launch_chain(in.means.data_ptr<float>(), in.scales.data_ptr<float>(), in.rotations.data_ptr<float>(), chunk,
                 sd.tile_counts.data_ptr<int>(), rows, g.means.data_ptr<float>(),
                 g.scales.data_ptr<float>(), g.rotations.data_ptr<float>(), g.colors.data_ptr<float>(),
                 g.opacities.data_ptr<float>(), stream);
    check_launch("preprocess backward");
  }
  return g;
}

}  // namespace flat::surfels::cuda
