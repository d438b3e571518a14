// libtorch glue of the CUDA rasterizer: allocation, the per-view loop and the
// launch checks. Views are rendered one after another, so scratch memory is
// that of one view. Per view: cull all triangles, select the visible ones,
// compute their screen data (visible-list order), bin, sort, composite. The
// forward keeps per view only the sorted ids, the tile ranges, two per-pixel
// maps and the visible list; the backward recomputes the visible triangles'
// screen data (one cheap kernel) instead of storing it.
#include "render/cuda/raster_cuda.h"

#include <algorithm>
#include <limits>
#include <memory>
#include <vector>

#include <ATen/cuda/CUDAContext.h>
#include <ATen/cuda/CUDAEvent.h>
#include <c10/cuda/CUDAGuard.h>
#include <spdlog/spdlog.h>

#include "flat/core/error.h"
#include "render/cuda/raster_kernels.h"

namespace flat::render::cuda {

void check_launch(const char* what) {
  const cudaError_t err = cudaGetLastError();
  if (err != cudaSuccess) fail(std::string("rasterize (cuda): ") + what + " failed: " + cudaGetErrorString(err));
}

namespace {

void copy_async(void* dst, const void* src, int64_t bytes, cudaStream_t stream) {
  const cudaError_t err = bytes > 0 ? cudaMemcpyAsync(dst, src, bytes, cudaMemcpyDeviceToDevice, stream) : cudaSuccess;
  if (err != cudaSuccess) fail(std::string("rasterize (cuda): device copy failed: ") + cudaGetErrorString(err));
}

void zero_async(const at::Tensor& t, cudaStream_t stream) {
  const cudaError_t err = t.numel() > 0 ? cudaMemsetAsync(t.data_ptr(), 0, t.nbytes(), stream) : cudaSuccess;
  if (err != cudaSuccess) fail(std::string("rasterize (cuda): memset failed: ") + cudaGetErrorString(err));
}

constexpr int64_t kTriFloats = sizeof(PixelTri<float>) / sizeof(float);
// Per view, kept for the backward: sorted ids, tile ranges, final T, last
// entry, visible list, the visible triangles' screen data (empty when over
// kKeepScreenBytes: the backward then recomputes it), the tiles' compositing
// order and the entries' coverage masks (PairMasks).
constexpr int64_t kViewState = 8;
// Screen data and coverage masks kept across views, at most (bytes); the
// masks are always kept and count first. At the paper's scale (24 views,
// ~1.5M visible triangles each) it all fits and the backward skips 24
// recomputations of the screen data (~2.5 ms on an H100); larger renders fall
// back to recomputing, keeping peak memory bounded. 5.25 GiB: anchor-large (24
// views, 2.5M visible triangles, 242 MB of screen data and 41 MB of masks
// each) keeps the screen data of 19 of its views, at 7.94 GiB of peak memory
// (the backward's two gradient buffers included, see backward()).
constexpr int64_t kKeepScreenBytes = int64_t(21) << 28;
static_assert(sizeof(PixelTri<float>) % sizeof(float) == 0, "PixelTri must be a whole number of floats");
static_assert(sizeof(TriGrad<float>) == kTriGradSize * sizeof(float), "TriGrad layout");
static_assert(sizeof(TriRect) == 4 * sizeof(int), "TriRect layout");

ViewParams make_params(const RasterInputs& in, const at::Tensor& w2c_cpu, const at::Tensor& K_cpu,
                       const at::Tensor& bg_cpu, int64_t view) {
  ViewParams vp;
  vp.cam = make_camera_view(w2c_cpu.data_ptr<float>() + 16 * view, K_cpu.data_ptr<float>() + 4 * view);
  vp.k = in.k;
  vp.width = (int)in.width;
  vp.height = (int)in.height;
  vp.tiles_x = (int)((in.width + kTileSize - 1) / kTileSize);
  vp.tiles_y = (int)((in.height + kTileSize - 1) / kTileSize);
  for (int c = 0; c < 3; ++c) vp.background[c] = bg_cpu.data_ptr<float>()[c];
  vp.inv_fx = 1.f / vp.cam.fx;
  vp.inv_fy = 1.f / vp.cam.fy;
  return vp;
}

void check_sizes(const RasterInputs& in) {
  FLAT_CHECK(in.vertices.scalar_type() == at::kFloat, "rasterize (cuda): expected float32 tensors");
  FLAT_CHECK(in.vertices.size(0) < std::numeric_limits<int32_t>::max(),
             "rasterize (cuda): at most 2^31-1 triangles, got " + std::to_string(in.vertices.size(0)));
}

// One view's culling and binning state over all N triangles. kCullAhead + 1
// of them take turns: view v + kCullAhead is culled on a side stream while
// view v is binned and composited, so the host's one wait per view (for the
// sizes of the view's buffers) finds them ready, and the host can enqueue
// views ahead of the GPU instead of idling it. (One, two or three views
// ahead timed the same within run-to-run noise on the H100; two is kept.)
constexpr int kCullAhead = 2;
struct CullScratch {
  at::Tensor rects, counts, keys, visible, num_visible, total, select_temp;
  at::Tensor host_count, host_visible;  // pinned: the sizes the host needs
  at::cuda::CUDAEvent culled, released;  // sizes ready (side stream); last read done (main stream)
  size_t select_bytes = 0;
  CullScratch(int64_t n, const at::TensorOptions& f, cudaStream_t stream) {
    rects = at::empty({n * 4}, f.dtype(at::kInt));
    counts = at::empty({n}, f.dtype(at::kInt));
    keys = at::empty({n}, f);
    visible = at::empty({n}, f.dtype(at::kInt));
    num_visible = at::empty({1}, f.dtype(at::kInt));
    total = at::empty({1}, f.dtype(at::kLong));
    select_visible(nullptr, select_bytes, nullptr, n, nullptr, nullptr, stream);
    select_temp = at::empty({(int64_t)select_bytes + 1}, f.dtype(at::kByte));
    host_count = at::zeros({1}, at::TensorOptions().dtype(at::kLong).pinned_memory(true));
    host_visible = at::zeros({1}, at::TensorOptions().dtype(at::kInt).pinned_memory(true));
  }
  TriRect* rect_ptr() { return reinterpret_cast<TriRect*>(rects.data_ptr<int>()); }

  // Enqueues culling (with the pair count) and the visible selection of one view on
  // `side` (after the previous user of this scratch released it), and the
  // copy of the two sizes to the host.
  void cull(const RasterInputs& in, const ViewParams& vp, const c10::cuda::CUDAStream& side) {
    const int64_t n = in.vertices.size(0);
    released.block(side);
    launch_cull(in.vertices.data_ptr<float>(), in.opacities.data_ptr<float>(), n, vp, rect_ptr(),
                counts.data_ptr<int>(), keys.data_ptr<float>(), total.data_ptr<int64_t>(), side);
    check_launch("culling");
    select_visible(select_temp.data_ptr(), select_bytes, counts.data_ptr<int>(), n, visible.data_ptr<int>(),
                   num_visible.data_ptr<int>(), side);
    check_launch("visible selection");
    FLAT_CHECK(cudaMemcpyAsync(host_count.data_ptr(), total.data_ptr<int64_t>(), sizeof(int64_t),
                               cudaMemcpyDeviceToHost, side) == cudaSuccess &&
                   cudaMemcpyAsync(host_visible.data_ptr(), num_visible.data_ptr(), sizeof(int32_t),
                                   cudaMemcpyDeviceToHost, side) == cudaSuccess,
               "rasterize (cuda): copying the view sizes to the host failed");
    culled.record(side);
  }
};

// Screen data of one view's visible triangles, in visible-list order.
struct ScreenData {
  at::Tensor tris, rects;
  // with_rects: the forward's binning and compositing need the rectangles
  // (copied from cull_rects); the backward does not.
  ScreenData(const RasterInputs& in, const at::Tensor& visible, const ViewParams& vp, const TriRect* cull_rects,
             bool with_rects, cudaStream_t stream) {
    const int64_t nv = visible.size(0);
    const auto f = in.vertices.options();
    tris = at::empty({nv * kTriFloats}, f);
    rects = at::empty({with_rects ? nv * 4 : 0}, f.dtype(at::kInt));
    launch_screen(in.vertices.data_ptr<float>(), in.colors.data_ptr<float>(), in.opacities.data_ptr<float>(),
                  in.sigmas.data_ptr<float>(), visible.data_ptr<int>(), nv, vp, cull_rects, tri_ptr(),
                  with_rects ? rect_ptr() : nullptr, stream);
    check_launch("screen preprocessing");
  }
  PixelTri<float>* tri_ptr() { return reinterpret_cast<PixelTri<float>*>(tris.data_ptr<float>()); }
  TriRect* rect_ptr() { return reinterpret_cast<TriRect*>(rects.data_ptr<int>()); }
  int64_t tri_bytes() const { return tris.nbytes(); }
};

// One view's binning buffers, carved from a single allocation (one
// allocator call a view instead of ten: the host's per-view work is what
// small renders wait on): the depth keys and orders before and after the
// depth sort, the depth-order offsets, the pairs before the tile sort, and
// the sorts' and scan's temporary storage.
struct BinScratch {
  at::Tensor bytes;
  uint32_t *depth_bits, *depth_sorted, *tiles, *tiles_sorted;
  int32_t *order, *order_sorted, *counts, *offsets, *ids;
  void* temp;
  size_t depth_bytes = 0, scan_bytes = 0, tile_bytes = 0;
  BinScratch(int64_t nv, int64_t count, int num_tiles, const at::TensorOptions& f, cudaStream_t stream) {
    sort_by_depth(nullptr, depth_bytes, nullptr, nullptr, nullptr, nullptr, nv, stream);
    scan_ordered_counts(nullptr, scan_bytes, nullptr, nullptr, nv, stream);
    sort_by_tile(nullptr, tile_bytes, nullptr, nullptr, nullptr, nullptr, count, num_tiles, stream);
    auto aligned = [](size_t b) { return (b + 255) / 256 * 256; };
    const size_t per_tri = aligned(nv * sizeof(int32_t)), per_pair = aligned(count * sizeof(int32_t));
    const size_t temp_bytes = aligned(std::max({depth_bytes, scan_bytes, tile_bytes, size_t(1)}));
    bytes = at::empty({(int64_t)(6 * per_tri + 3 * per_pair + temp_bytes)}, f.dtype(at::kByte));
    char* p = reinterpret_cast<char*>(bytes.data_ptr());
    auto take = [&](size_t b) {
      char* q = p;
      p += b;
      return q;
    };
    depth_bits = reinterpret_cast<uint32_t*>(take(per_tri));
    depth_sorted = reinterpret_cast<uint32_t*>(take(per_tri));
    order = reinterpret_cast<int32_t*>(take(per_tri));
    order_sorted = reinterpret_cast<int32_t*>(take(per_tri));
    counts = reinterpret_cast<int32_t*>(take(per_tri));
    offsets = reinterpret_cast<int32_t*>(take(per_tri));
    tiles = reinterpret_cast<uint32_t*>(take(per_pair));
    tiles_sorted = reinterpret_cast<uint32_t*>(take(per_pair));
    ids = reinterpret_cast<int32_t*>(take(per_pair));
    temp = take(temp_bytes);
  }
};

// Sorts one view's visible triangles by depth (keys and order in bs, from
// launch_depth_keys), writes their (tile, triangle) pairs in that order and
// sorts those by tile (binning.cu): returns the pairs' visible-list indices,
// tile by tile, front to back, fills ranges, and puts the tiles in
// compositing order (heaviest first) into tile_order.
at::Tensor bin_by_tile(BinScratch& bs, int64_t nv, ScreenData& sd, int64_t count, const ViewParams& vp,
                       at::Tensor& ranges, at::Tensor& tile_order, cudaStream_t stream) {
  const int num_tiles = vp.tiles_x * vp.tiles_y;
  at::Tensor ids_sorted = at::empty({count}, ranges.options());
  sort_by_depth(bs.temp, bs.depth_bytes, bs.depth_bits, bs.depth_sorted, bs.order, bs.order_sorted, nv, stream);
  check_launch("depth sort");
  launch_ordered_counts(bs.order_sorted, nv, sd.rect_ptr(), bs.counts, stream);
  scan_ordered_counts(bs.temp, bs.scan_bytes, bs.counts, bs.offsets, nv, stream);
  check_launch("tile count scan (depth order)");
  launch_duplicate(bs.order_sorted, nv, sd.rect_ptr(), sd.tri_ptr(), vp, bs.offsets, bs.tiles, bs.ids, stream);
  check_launch("duplicate");
  sort_by_tile(bs.temp, bs.tile_bytes, bs.tiles, bs.tiles_sorted, bs.ids, ids_sorted.data_ptr<int>(), count, num_tiles,
               stream);
  check_launch("tile sort");
  launch_tile_ranges(bs.tiles_sorted, count, reinterpret_cast<int2*>(ranges.data_ptr<int>()), stream);
  check_launch("tile ranges");
  launch_tile_order(reinterpret_cast<const int2*>(ranges.data_ptr<int>()), num_tiles, tile_order.data_ptr<int>(),
                    stream);
  check_launch("tile order");
  return ids_sorted;
}

// One view's load (raster_load.h): the list lengths from the tile ranges,
// the entries per pixel from the forward's per-pixel last blended entry.
ViewLoad count_load(int64_t visible, int64_t pairs, const at::Tensor& ranges, const at::Tensor& last) {
  const at::Tensor list = (ranges.select(1, 1) - ranges.select(1, 0)).to(at::kDouble);
  const at::Tensor entries = last.to(at::kDouble);
  const at::Tensor s = at::stack({list.mean(), list.max(), entries.mean(), entries.max()}).cpu();
  const double* d = s.data_ptr<double>();
  return ViewLoad{visible, pairs, d[0], (int64_t)d[1], d[2], (int64_t)d[3]};
}

}  // namespace

RasterOutputs forward(const RasterInputs& in, bool for_backward, std::vector<at::Tensor>& views,
                      std::vector<ViewLoad>* load) {
  check_sizes(in);
  const c10::cuda::CUDAGuard guard(in.vertices.device());
  const cudaStream_t stream = at::cuda::getCurrentCUDAStream();
  const int64_t N = in.vertices.size(0), V = in.w2c.size(0), H = in.height, W = in.width;
  const auto f = in.vertices.options();
  RasterOutputs out = RasterOutputs::images_for(in);
  at::Tensor max_bits = at::zeros({N}, f.dtype(at::kInt));
  const at::Tensor w2c_cpu = in.w2c.cpu(), K_cpu = in.K.cpu(), bg_cpu = in.background.cpu();
  std::vector<std::unique_ptr<CullScratch>> scratch;
  for (int i = 0; i <= kCullAhead; ++i) scratch.push_back(std::make_unique<CullScratch>(N, f, stream));
  const c10::cuda::CUDAStream side = c10::cuda::getStreamFromPool(false, in.vertices.device().index());
  at::cuda::CUDAEvent inputs_ready;
  inputs_ready.record(at::cuda::getCurrentCUDAStream());
  inputs_ready.block(side);  // the inputs may have been written on the main stream
  // Leaving early (an error below) must not free the scratch under a running cull.
  struct SideDrain {
    const c10::cuda::CUDAStream& stream;
    ~SideDrain() { stream.synchronize(); }
  } drain{side};
  for (int64_t a = 0; N > 0 && a < std::min<int64_t>(kCullAhead, V); ++a)
    scratch[a]->cull(in, make_params(in, w2c_cpu, K_cpu, bg_cpu, a), side);
  views.clear();
  int64_t kept_bytes = 0;
  const int64_t HW = H * W;
  for (int64_t v = 0; v < V; ++v) {
    CullScratch& s = *scratch[v % (kCullAhead + 1)];
    const ViewParams vp = make_params(in, w2c_cpu, K_cpu, bg_cpu, v);
    const int num_tiles = vp.tiles_x * vp.tiles_y;
    int64_t count = 0, nv = 0;
    if (N > 0) {
      // The one host wait per view: the sizes of the visible list and of the
      // pair buffers. View v - 1 may still be compositing meanwhile.
      s.culled.synchronize();
      s.culled.block(at::cuda::getCurrentCUDAStream());
      // The inputs' value statistics were copied before the first cull
      // (rasterize.cpp): checked at this first wait, not with a sync of their
      // own, and before any size the culling computed from the values is used.
      if (v == 0) check_input_values(in);
      count = s.host_count.data_ptr<int64_t>()[0];
      nv = s.host_visible.data_ptr<int>()[0];
    }
    FLAT_CHECK(count <= std::numeric_limits<int32_t>::max(),
               "rasterize (cuda): view " + std::to_string(v) + " needs " + std::to_string(count) +
                   " (triangle, tile) pairs, more than the 2^31-1 the sort supports; render fewer or smaller triangles");
    FLAT_CHECK(nv <= kMaxVisible, "rasterize (cuda): view " + std::to_string(v) + " has " + std::to_string(nv) +
                                      " visible triangles, more than the " + std::to_string(kMaxVisible) +
                                      " the tile lists can index; render fewer triangles per call");
    // Raw copies and memsets below: ATen's clone and zeros cost the host more,
    // and small renders wait on the host.
    const at::Tensor visible = at::empty({nv}, f.dtype(at::kInt));  // kept for the backward (4 bytes a triangle)
    copy_async(visible.data_ptr(), s.visible.data_ptr(), nv * sizeof(int32_t), stream);
    ScreenData sd(in, visible, vp, s.rect_ptr(), true, stream);
    at::Tensor ids_sorted, ranges = at::empty({num_tiles, 2}, f.dtype(at::kInt)), tile_order;
    zero_async(ranges, stream);
    BinScratch bs(nv, count, num_tiles, f, stream);
    launch_depth_keys(visible.data_ptr<int>(), nv, s.keys.data_ptr<float>(), bs.depth_bits, bs.order, stream);
    check_launch("depth keys");
    s.released.record(at::cuda::getCurrentCUDAStream());  // depth keys were the scratch's last reader
    const int64_t ahead = v + kCullAhead;  // its scratch was last read by view v - 1, released above
    if (N > 0 && ahead < V)
      scratch[ahead % (kCullAhead + 1)]->cull(in, make_params(in, w2c_cpu, K_cpu, bg_cpu, ahead), side);
    if (count > 0) {
      tile_order = at::empty({num_tiles}, f.dtype(at::kInt));
      ids_sorted = bin_by_tile(bs, nv, sd, count, vp, ranges, tile_order, stream);
    } else {
      ids_sorted = at::empty({0}, f.dtype(at::kInt));
      tile_order = at::arange(num_tiles, f.dtype(at::kInt));  // every tile is composited (the background)
    }
    bs.bytes = at::Tensor();
    at::Tensor t_final = at::empty({H, W}, f), last = at::empty({H, W}, f.dtype(at::kInt));
    const at::Tensor masks = at::empty({for_backward ? 2 * count : 0}, f.dtype(at::kInt));
    ForwardImages img{out.rgb.data_ptr<float>() + v * 3 * HW,    out.alpha.data_ptr<float>() + v * HW,
                      out.depth.data_ptr<float>() + v * HW,      out.normal.data_ptr<float>() + v * 3 * HW,
                      out.median_depth.data_ptr<float>() + v * HW, t_final.data_ptr<float>(),
                      last.data_ptr<int>(),
                      PairMasks{for_backward ? reinterpret_cast<uint32_t*>(masks.data_ptr<int>()) : nullptr, count}};
    launch_raster_forward(reinterpret_cast<const int2*>(ranges.data_ptr<int>()), tile_order.data_ptr<int>(),
                          ids_sorted.data_ptr<int>(), sd.tri_ptr(), sd.rect_ptr(), vp, img,
                          reinterpret_cast<unsigned int*>(max_bits.data_ptr<int>()), stream);
    check_launch("forward rasterization");
    if (load || spdlog::should_log(spdlog::level::debug)) {  // workload counts (host syncs)
      const ViewLoad l = count_load(nv, count, ranges, last);
      if (load) load->push_back(l);
      spdlog::debug("raster view {}: {} visible triangles, {} (triangle, tile) pairs, tile list mean {:.1f} max {}, "
                    "entries per pixel mean {:.1f} max {}",
                    v, l.visible, l.tile_pairs, l.list_mean, l.list_max, l.entries_mean, l.entries_max);
    }
    if (for_backward) {
      kept_bytes += masks.nbytes();
      const bool keep = kept_bytes + sd.tri_bytes() <= kKeepScreenBytes;
      if (keep) kept_bytes += sd.tri_bytes();
      views.insert(views.end(), {ids_sorted, ranges, t_final, last, visible, keep ? sd.tris : at::empty({0}, f),
                                 tile_order, masks});
    }
  }
  if (V == 0) {  // no view waited for the device: the value checks still hold
    at::cuda::getCurrentCUDAStream().synchronize();
    check_input_values(in);
  }
  out.max_weight = max_bits.view(at::kFloat);  // non-negative floats: integer max == float max
  return out;
}

RasterGrads backward(const RasterInputs& in, const std::vector<at::Tensor>& views, const at::Tensor& grad_rgb,
                     const at::Tensor& grad_alpha, const at::Tensor& grad_depth, const at::Tensor& grad_normal) {
  check_sizes(in);
  const c10::cuda::CUDAGuard guard(in.vertices.device());
  const cudaStream_t stream = at::cuda::getCurrentCUDAStream();
  const int64_t N = in.vertices.size(0), V = in.w2c.size(0), H = in.height, W = in.width, HW = H * W;
  FLAT_CHECK((int64_t)views.size() == kViewState * V, "rasterize (cuda): backward state does not match the views");
  const auto f = in.vertices.options();
  RasterGrads g;
  g.vertices = at::zeros_like(in.vertices);
  g.colors = at::zeros_like(in.colors);
  g.opacities = at::zeros_like(in.opacities);
  g.sigmas = at::zeros_like(in.sigmas);
  if (N == 0) return g;
  const at::Tensor w2c_cpu = in.w2c.cpu(), K_cpu = in.K.cpu(), bg_cpu = in.background.cpu();
  // Per-triangle screen gradients of kChainViews views (visible-list rows, as
  // many as the longest list) and their row maps; the chain rule runs once
  // per group of views (launch_chain) and resets both, so they are set once.
  int64_t rows = 0;
  for (int64_t v = 0; v < V; ++v) rows = std::max(rows, views[kViewState * v + 4].size(0));
  const at::Tensor tri_grads = at::zeros({kChainViews, rows * kTriGradStride}, f);
  const at::Tensor row_of = at::full({kChainViews, N}, -1, f.dtype(at::kInt));
  ChainViews group;
  auto chain = [&] {
    launch_chain(in.vertices.data_ptr<float>(), N, group, g.vertices.data_ptr<float>(), g.colors.data_ptr<float>(),
                 g.opacities.data_ptr<float>(), g.sigmas.data_ptr<float>(), stream);
    check_launch("preprocess backward");
    group.count = 0;
  };
  for (int64_t v = 0; v < V; ++v) {
    const at::Tensor& visible = views[kViewState * v + 4];
    const int64_t nv = visible.size(0);
    if (nv == 0) continue;
    const ViewParams vp = make_params(in, w2c_cpu, K_cpu, bg_cpu, v);
    at::Tensor tris = views[kViewState * v + 5];  // kept, or recomputed here
    if (tris.numel() == 0) tris = ScreenData(in, visible, vp, nullptr, false, stream).tris;
    const at::Tensor& masks = views[kViewState * v + 7];
    const at::Tensor& ids = views[kViewState * v];
    const at::Tensor& ranges = views[kViewState * v + 1];
    BackwardImages img{grad_rgb.data_ptr<float>() + v * 3 * HW, grad_alpha.data_ptr<float>() + v * HW,
                       grad_depth.data_ptr<float>() + v * HW,  grad_normal.data_ptr<float>() + v * 3 * HW,
                       views[kViewState * v + 2].data_ptr<float>(), views[kViewState * v + 3].data_ptr<int>(),
                       PairMasks{reinterpret_cast<uint32_t*>(masks.data_ptr<int>()), masks.numel() / 2}};
    const int slot = group.count++;
    group.cam[slot] = vp.cam;
    group.tri_grads[slot] = tri_grads[slot].data_ptr<float>();
    group.row_of[slot] = row_of[slot].data_ptr<int>();
    launch_raster_backward(reinterpret_cast<const int2*>(ranges.data_ptr<int>()),
                           views[kViewState * v + 6].data_ptr<int>(), ids.data_ptr<int>(),
                           reinterpret_cast<const PixelTri<float>*>(tris.data_ptr<float>()), vp, img,
                           group.tri_grads[slot], stream);
    check_launch("backward rasterization");
    launch_row_map(visible.data_ptr<int>(), nv, group.row_of[slot], stream);
    check_launch("row map");
    if (group.count == kChainViews) chain();
  }
  if (group.count > 0) chain();
  return g;
}

}  // namespace flat::render::cuda
