// libtorch glue of the CUDA rasterizer: allocation, the per-view loop and the
// launch checks. Views are rendered one bin group (two views, or one:
// RasterSettings::views_per_bin) after another, so scratch memory is that of
// one group.
// Per view: cull all triangles and select the visible ones; per group:
// compute their screen data (the group's list: its views' visible lists one
// after another), bin, sort and composite (one launch for the group's views).
// The forward keeps
// per view only the sorted ids, the tile ranges, two per-pixel maps and the
// visible list (and the screen data while it fits kKeepScreenBytes; else the
// backward recomputes it, one cheap kernel).
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

void zero_async(const at::Tensor& t, cudaStream_t stream) {
  const cudaError_t err = t.numel() > 0 ? cudaMemsetAsync(t.data_ptr(), 0, t.nbytes(), stream) : cudaSuccess;
  if (err != cudaSuccess) fail(std::string("rasterize (cuda): memset failed: ") + cudaGetErrorString(err));
}

constexpr int64_t kTriFloats = sizeof(PixelTri<float>) / sizeof(float);
// Per view, kept for the backward. The ids, screen data and masks are the bin
// group's (the same tensors for each of its views), the visible list a slice
// of the group's (SavedGroup). Autograd keeps a flat tensor list: append_to
// and of() are the one place that knows its order.
struct ViewState {
  at::Tensor ids_sorted;  // the group's (triangle, tile) entries' triangle ids, sorted
  at::Tensor ranges;      // per tile [start, end) into ids_sorted (int2)
  at::Tensor t_final;     // per pixel, the final transmittance
  at::Tensor last;        // per pixel, the number of entries processed
  at::Tensor visible;     // the view's visible triangles
  at::Tensor screen;      // the group's visible triangles' screen data; empty over
                          // kKeepScreenBytes (the backward then recomputes it)
  at::Tensor tile_order;  // the tiles' compositing order
  at::Tensor masks;       // the entries' coverage masks (PairMasks)

  static constexpr int64_t kFields = 8;
  void append_to(std::vector<at::Tensor>& list) const {
    list.insert(list.end(), {ids_sorted, ranges, t_final, last, visible, screen, tile_order, masks});
  }
  static ViewState of(const std::vector<at::Tensor>& list, int64_t view) {
    const at::Tensor* t = list.data() + kFields * view;
    return {t[0], t[1], t[2], t[3], t[4], t[5], t[6], t[7]};
  }
};
// Screen data and coverage masks kept across views, at most (bytes); the
// masks are always kept and count first. At the paper's scale (24 views,
// ~1.5M visible triangles each) it all fits and the backward skips 24
// recomputations of the screen data (~2.5 ms on an H100); larger renders fall
// back to recomputing, keeping peak memory bounded. 5.25 GiB: anchor-large (24
// views, 2.5M visible triangles, 242 MB of screen data and 41 MB of masks
// each; kept a bin group at a time) keeps the screen data of 9 of its 12
// groups (18 views), at 7.92 GiB of peak memory (the backward's gradient
// buffer, two views' rows, included; see backward()).
constexpr int64_t kKeepScreenBytes = int64_t(21) << 28;
static_assert(sizeof(PixelTri<float>) % sizeof(float) == 0, "PixelTri must be a whole number of floats");
static_assert(sizeof(TriGrad<float>) == kTriGradSize * sizeof(float), "TriGrad layout");
static_assert(sizeof(TriRect) == 4 * sizeof(int), "TriRect layout");

ViewParams make_params(const RasterInputs& in, const at::Tensor& w2c_cpu, const at::Tensor& K_cpu,
                       const at::Tensor& bg_cpu, int64_t view) {
  ViewParams vp;
  static_cast<TileView<RasterConstants>&>(vp) =
      make_tile_view(w2c_cpu.data_ptr<float>() + 16 * view, K_cpu.data_ptr<float>() + 4 * view, in.k, in.width,
                     in.height, kTileSize, bg_cpu.data_ptr<float>());
  vp.inv_fx = 1.f / vp.cam.fx;
  vp.inv_fy = 1.f / vp.cam.fy;
  return vp;
}

void check_sizes(const RasterInputs& in) {
  FLAT_CHECK(in.vertices.scalar_type() == at::kFloat, "rasterize (cuda): expected float32 tensors");
  FLAT_CHECK(in.vertices.size(0) < std::numeric_limits<int32_t>::max(),
             "rasterize (cuda): at most 2^31-1 triangles, got " + std::to_string(in.vertices.size(0)));
}

// One view's culling state over all N triangles. Views are culled on a side
// stream kCullAhead bin groups ahead of the group being binned and
// composited (a ring of (kCullAhead + 1) x the group size of these), so the
// host's one wait per view (for the sizes of the view's buffers) finds them
// ready, and the host can enqueue views ahead of the GPU instead of idling
// it. (One group ahead timed as two with two-view groups on the H100, at
// two views' scratch less; with one-view groups one, two or three views
// ahead had timed the same.)
constexpr int kCullAhead = 1;
struct CullScratch {
  at::Tensor rects, counts, keys, visible, num_visible, total, select_temp;
  at::Tensor host_count, host_visible;  // pinned: the sizes the host needs
  at::cuda::CUDAEvent culled, released;  // sizes ready (side stream); last read done (main stream)
  size_t select_bytes = 0;
  CullScratch(int64_t n, const at::TensorOptions& f, const c10::cuda::CUDAStream& main) {
    const cudaStream_t stream = main.stream();
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
    // Allocated on the main stream, written on the side stream: the first
    // cull waits for the main stream's work so far (which may still read
    // memory freed earlier in the call and handed out again here).
    released.record(main);
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

// Screen data of a bin group's visible triangles, in group-list order (each
// view's rows from its first row on, add()).
struct ScreenData {
  at::Tensor tris, rects;
  // with_rects: the forward's binning and compositing need the rectangles
  // (copied from the cull pass's); the backward does not.
  ScreenData(int64_t rows, bool with_rects, const at::TensorOptions& f)
      : tris(at::empty({rows * kTriFloats}, f)), rects(at::empty({with_rects ? rows * 4 : 0}, f.dtype(at::kInt))) {}
  // Rows [first, first + nv): the triangles visible[0..nv) of one view.
  // cull_rects: that view's cull-pass rectangles (nullptr: recomputed).
  // visible_out: where visible is copied as well (nullptr: nowhere).
  void add(const RasterInputs& in, const int32_t* visible, int64_t nv, int64_t first, const ViewParams& vp,
           const TriRect* cull_rects, int32_t* visible_out, cudaStream_t stream) {
    launch_screen(in.vertices.data_ptr<float>(), in.colors.data_ptr<float>(), in.opacities.data_ptr<float>(),
                  in.sigmas.data_ptr<float>(), visible, nv, vp, cull_rects, tri_ptr() + first,
                  rects.numel() > 0 ? rect_ptr() + first : nullptr, visible_out, stream);
    check_launch("screen preprocessing");
  }
  PixelTri<float>* tri_ptr() { return reinterpret_cast<PixelTri<float>*>(tris.data_ptr<float>()); }
  TriRect* rect_ptr() { return reinterpret_cast<TriRect*>(rects.data_ptr<int>()); }
  int64_t tri_bytes() const { return tris.nbytes(); }
};

// The temporary storage cub's sorts and scan need, asked again only when a
// group has more rows or pairs than any before it in the call, not once per
// group (each ask costs the host device queries; the sizes only grow with
// the item count). The tile sort's is asked for the largest group's tiles.
struct TempSizes {
  size_t depth = 0, scan = 0, tile = 0;
  int64_t rows = -1, pairs = -1;
  int max_tiles = 0;
  explicit TempSizes(int max_group_tiles) : max_tiles(max_group_tiles) {}
  void fit(int64_t group_rows, int64_t group_pairs, cudaStream_t stream) {
    if (group_rows > rows) {
      sort_by_depth(nullptr, depth, nullptr, nullptr, nullptr, nullptr, group_rows, stream);
      scan_counts(nullptr, scan, nullptr, nullptr, group_rows, stream);
      rows = group_rows;
    }
    if (group_pairs > pairs) {
      sort_by_tile(nullptr, tile, nullptr, nullptr, nullptr, nullptr, group_pairs, max_tiles, stream);
      pairs = group_pairs;
    }
  }
};

// A bin group's binning buffers, carved from a single allocation (one
// allocator call a group instead of ten: the host's per-view work is what
// small renders wait on): the depth keys and orders before and after the
// depth sort, the depth-order offsets, the pairs before the tile sort, and
// the sorts' and scan's temporary storage.
struct BinScratch {
  at::Tensor bytes;
  uint32_t *depth_bits, *depth_sorted, *tiles, *tiles_sorted;
  int32_t *order, *order_sorted, *counts, *offsets, *ids;
  void* temp;
  size_t depth_bytes = 0, scan_bytes = 0, tile_bytes = 0;
  BinScratch(int64_t nv, int64_t count, TempSizes& sizes, const at::TensorOptions& f, cudaStream_t stream) {
    sizes.fit(nv, count, stream);
    depth_bytes = sizes.depth, scan_bytes = sizes.scan, tile_bytes = sizes.tile;
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

// Sorts a bin group's visible triangles by depth (keys and order in bs, from
// launch_depth_keys), writes their (tile, triangle) pairs in that order and
// sorts those by tile (binning.cu): returns the pairs' group-list indices,
// tile by tile, front to back, and fills ranges (group_tiles of them: the
// group's views one after another). second: the second view's first row.
at::Tensor bin_by_tile(BinScratch& bs, int64_t rows, ScreenData& sd, int64_t pairs, const ViewParams& vp,
                       int64_t second, int group_tiles, at::Tensor& ranges, cudaStream_t stream) {
  at::Tensor ids_sorted = at::empty({pairs}, ranges.options());
  sort_by_depth(bs.temp, bs.depth_bytes, bs.depth_bits, bs.depth_sorted, bs.order, bs.order_sorted, rows, stream);
  check_launch("depth sort");
  launch_ordered_counts(bs.order_sorted, rows, sd.rect_ptr(), bs.counts, stream);
  scan_counts(bs.temp, bs.scan_bytes, bs.counts, bs.offsets, rows, stream);
  check_launch("tile count scan (depth order)");
  launch_duplicate(bs.order_sorted, rows, sd.rect_ptr(), sd.tri_ptr(), vp, (int32_t)second, bs.offsets, bs.tiles,
                   bs.ids, stream);
  check_launch("duplicate");
  sort_by_tile(bs.temp, bs.tile_bytes, bs.tiles, bs.tiles_sorted, bs.ids, ids_sorted.data_ptr<int>(), pairs,
               group_tiles, stream);
  check_launch("tile sort");
  launch_tile_ranges(bs.tiles_sorted, pairs, reinterpret_cast<int2*>(ranges.data_ptr<int>()), stream);
  check_launch("tile ranges");
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

// One view of a bin group in the forward: its cull state, its sizes and its
// first row in the group's visible list.
struct GroupView {
  int64_t view = 0, nv = 0, pairs = 0, first = 0;
  CullScratch* cull = nullptr;
  ViewParams vp;
};

// The group's pixel rays (GroupRays) from its views' parameters, n of them.
GroupRays group_rays(const ViewParams* vps, int n) {
  GroupRays r;
  r.views = n;
  for (int j = 0; j < n; ++j)
    r.cx[j] = vps[j].cam.cx, r.cy[j] = vps[j].cam.cy, r.inv_fx[j] = vps[j].inv_fx, r.inv_fy[j] = vps[j].inv_fy;
  return r;
}

// A bin group in the backward state: its views share the ids, screen data and
// mask tensors (the forward stores them with each view), and each view's
// visible list is a slice of the group's (its storage offset is its first
// row there).
struct SavedGroup {
  int64_t first_view = 0, views = 0, rows = 0;
  int live = 0;  // views with visible triangles
};
std::vector<SavedGroup> saved_groups(const std::vector<at::Tensor>& views, int64_t V) {
  std::vector<SavedGroup> groups;
  for (int64_t v = 0; v < V; ++v) {
    if (v == 0 || !ViewState::of(views, v).ids_sorted.is_same(ViewState::of(views, v - 1).ids_sorted))
      groups.push_back({v, 0, 0, 0});
    const int64_t nv = ViewState::of(views, v).visible.numel();
    SavedGroup& g = groups.back();
    g.views += 1;
    g.rows += nv;
    g.live += nv > 0;
  }
  return groups;
}

}  // namespace

RasterOutputs forward(const RasterInputs& in, bool for_backward, std::vector<at::Tensor>& views,
                      std::vector<ViewLoad>* load) {
  check_sizes(in);
  const c10::cuda::CUDAGuard guard(in.vertices.device());
  const cudaStream_t stream = at::cuda::getCurrentCUDAStream();
  const int64_t N = in.vertices.size(0), V = in.w2c.size(0), H = in.height, W = in.width;
  const auto f = in.vertices.options();
  RasterOutputs out = images_for(in);
  at::Tensor max_bits = at::zeros({N}, f.dtype(at::kInt));
  const at::Tensor w2c_cpu = in.w2c.cpu(), K_cpu = in.K.cpu(), bg_cpu = in.background.cpu();
  // Two views a group by default: the host's work per view (~340 us on
  // anchor-small, two thirds of it the sorts' and binning's launches), which
  // small renders wait on, is paid once for both, and the sorts and binning
  // kernels fill the GPU better (anchor-small 12.5 -> 11.6 ms, anchor-large
  // 59.4 -> 58.3 ms on the H100, same run).
  const int group_max = (int)std::clamp<int64_t>(in.views_per_bin, 1, kBinViews);
  // Views are culled kCullAhead groups ahead of the group being binned; the
  // ring holds those and the group's own.
  const int64_t ahead = kCullAhead * group_max, ring = ahead + group_max;
  // Each built when first used: the first cull starts after one is built,
  // not after all (the GPU would idle meanwhile).
  std::vector<std::unique_ptr<CullScratch>> scratch(ring);
  auto scratch_of = [&](int64_t view) -> CullScratch& {
    std::unique_ptr<CullScratch>& s = scratch[view % ring];
    if (!s) s = std::make_unique<CullScratch>(N, f, at::cuda::getCurrentCUDAStream());
    return *s;
  };
  const c10::cuda::CUDAStream side = c10::cuda::getStreamFromPool(false, in.vertices.device().index());
  at::cuda::CUDAEvent inputs_ready;
  inputs_ready.record(at::cuda::getCurrentCUDAStream());
  inputs_ready.block(side);  // the inputs may have been written on the main stream
  // Leaving early (an error below) must not free the scratch under a running cull.
  struct SideDrain {
    const c10::cuda::CUDAStream& stream;
    ~SideDrain() { stream.synchronize(); }
  } drain{side};
  for (int64_t a = 0; N > 0 && a < std::min<int64_t>(ahead, V); ++a)
    scratch_of(a).cull(in, make_params(in, w2c_cpu, K_cpu, bg_cpu, a), side);
  // A view's sizes: the one host wait per view (the group before may still be
  // compositing meanwhile).
  auto wait_for = [&](int64_t v) {
    GroupView g;
    g.view = v;
    g.cull = &scratch_of(v);
    g.vp = make_params(in, w2c_cpu, K_cpu, bg_cpu, v);
    if (N == 0) return g;
    g.cull->culled.synchronize();
    g.cull->culled.block(at::cuda::getCurrentCUDAStream());
    // The inputs' value statistics were copied before the first cull
    // (rasterize.cpp): checked at this first wait, not with a sync of their
    // own, and before any size the culling computed from the values is used.
    if (v == 0) check_input_values(in);
    g.pairs = g.cull->host_count.data_ptr<int64_t>()[0];
    g.nv = g.cull->host_visible.data_ptr<int>()[0];
    FLAT_CHECK(g.pairs <= std::numeric_limits<int32_t>::max(),
               "rasterize (cuda): view " + std::to_string(v) + " needs " + std::to_string(g.pairs) +
                   " (triangle, tile) pairs, more than the 2^31-1 the sort supports; render fewer or smaller triangles");
    FLAT_CHECK(g.nv <= kMaxVisible, "rasterize (cuda): view " + std::to_string(v) + " has " + std::to_string(g.nv) +
                                        " visible triangles, more than the " + std::to_string(kMaxVisible) +
                                        " the tile lists can index; render fewer triangles per call");
    return g;
  };
  views.clear();
  int64_t kept_bytes = 0;
  const int64_t HW = H * W;
  const int64_t tiles = ((W + kTileSize - 1) / kTileSize) * ((H + kTileSize - 1) / kTileSize);
  TempSizes temp_sizes((int)(group_max * tiles));
  for (int64_t v = 0; v < V;) {
    // The group: the next views while there is room and the group's sizes
    // stay within what the sort and the pair ids can index.
    GroupView group[kBinViews];
    int n = 0;
    int64_t rows = 0, pairs = 0;
    while (n < group_max && v + n < V) {
      GroupView g = wait_for(v + n);
      if (n > 0 && (rows + g.nv > kMaxVisible || pairs + g.pairs > std::numeric_limits<int32_t>::max())) break;
      g.first = rows;
      rows += g.nv;
      pairs += g.pairs;
      group[n++] = g;
    }
    v += n;
    const ViewParams& vp = group[0].vp;  // the views differ only in their cameras
    const int num_tiles = vp.tiles_x * vp.tiles_y, group_tiles = n * num_tiles;
    // Raw memsets below: ATen's zeros costs the host more, and small renders
    // wait on the host. The screen pass copies each view's visible list into
    // the group's (no copy launch of its own).
    const at::Tensor visible = at::empty({rows}, f.dtype(at::kInt));  // kept for the backward (4 bytes a triangle)
    ScreenData sd(rows, true, f);
    at::Tensor ranges = at::empty({group_tiles, 2}, f.dtype(at::kInt));
    zero_async(ranges, stream);
    BinScratch bs(rows, pairs, temp_sizes, f, stream);
    for (int j = 0; j < n; ++j) {
      const GroupView& g = group[j];
      const int32_t* cull_visible = g.cull->visible.data_ptr<int>();
      sd.add(in, cull_visible, g.nv, g.first, g.vp, g.cull->rect_ptr(), visible.data_ptr<int>() + g.first, stream);
      launch_depth_keys(cull_visible, g.nv, g.cull->keys.data_ptr<float>(), (int32_t)g.first, bs.depth_bits + g.first,
                        bs.order + g.first, stream);
      check_launch("depth keys");
      g.cull->released.record(at::cuda::getCurrentCUDAStream());  // depth keys were the scratch's last reader
    }
    for (int j = 0; j < n; ++j) {  // each one's scratch was last read by the group before, released above
      const int64_t next = group[j].view + ahead;
      if (N > 0 && next < V) scratch_of(next).cull(in, make_params(in, w2c_cpu, K_cpu, bg_cpu, next), side);
    }
    const int64_t second = n > 1 ? group[1].first : rows;
    const at::Tensor ids_sorted = pairs > 0 ? bin_by_tile(bs, rows, sd, pairs, vp, second, group_tiles, ranges, stream)
                                            : at::empty({0}, f.dtype(at::kInt));
    bs.bytes = at::Tensor();
    // Every tile is composited, those without entries too (the background).
    const at::Tensor tile_order = at::empty({group_tiles}, f.dtype(at::kInt));
    launch_tile_order(reinterpret_cast<const int2*>(ranges.data_ptr<int>()), num_tiles, n, tile_order.data_ptr<int>(),
                      stream);
    check_launch("tile order");
    const at::Tensor masks = at::empty({for_backward ? 2 * pairs : 0}, f.dtype(at::kInt));
    at::Tensor kept_tris = at::empty({0}, f);
    if (for_backward) {
      kept_bytes += masks.nbytes();
      if (kept_bytes + sd.tri_bytes() <= kKeepScreenBytes) {
        kept_bytes += sd.tri_bytes();
        kept_tris = sd.tris;
      }
    }
    // One compositing launch for the group's views (their images are
    // consecutive: the views are).
    const int64_t u0 = group[0].view;
    const at::Tensor t_final = at::empty({n, H, W}, f), last = at::empty({n, H, W}, f.dtype(at::kInt));
    ViewParams vps[kBinViews];
    for (int j = 0; j < n; ++j) vps[j] = group[j].vp;
    const GroupRays rays = group_rays(vps, n);
    ForwardImages img{out.rgb.data_ptr<float>() + u0 * 3 * HW,    out.alpha.data_ptr<float>() + u0 * HW,
                      out.depth.data_ptr<float>() + u0 * HW,      out.normal.data_ptr<float>() + u0 * 3 * HW,
                      out.median_depth.data_ptr<float>() + u0 * HW, t_final.data_ptr<float>(),
                      last.data_ptr<int>(),
                      PairMasks{for_backward ? reinterpret_cast<uint32_t*>(masks.data_ptr<int>()) : nullptr, pairs}};
    launch_raster_forward(reinterpret_cast<const int2*>(ranges.data_ptr<int>()), tile_order.data_ptr<int>(),
                          ids_sorted.data_ptr<int>(), sd.tri_ptr(), sd.rect_ptr(), vp, rays, img,
                          reinterpret_cast<unsigned int*>(max_bits.data_ptr<int>()), stream);
    check_launch("forward rasterization");
    for (int j = 0; j < n; ++j) {
      const GroupView& g = group[j];
      const int64_t u = g.view;
      const at::Tensor view_ranges = ranges.narrow(0, j * num_tiles, num_tiles);
      const at::Tensor view_order = tile_order.narrow(0, j * num_tiles, num_tiles);
      if (load || spdlog::should_log(spdlog::level::debug)) {  // workload counts (host syncs)
        const ViewLoad l = count_load(g.nv, g.pairs, view_ranges, last[j]);
        if (load) load->push_back(l);
        spdlog::debug("raster view {}: {} visible triangles, {} (triangle, tile) pairs, tile list mean {:.1f} max {}, "
                      "entries per pixel mean {:.1f} max {}",
                      u, l.visible, l.tile_pairs, l.list_mean, l.list_max, l.entries_mean, l.entries_max);
      }
      if (for_backward)
        ViewState{ids_sorted, view_ranges, t_final[j], last[j], visible.narrow(0, g.first, g.nv), kept_tris,
                  view_order, masks}
            .append_to(views);
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
  FLAT_CHECK((int64_t)views.size() == ViewState::kFields * V,
             "rasterize (cuda): backward state does not match the views");
  const auto f = in.vertices.options();
  RasterGrads g = RasterGrads::zeros_for(in);
  if (N == 0) return g;
  const at::Tensor w2c_cpu = in.w2c.cpu(), K_cpu = in.K.cpu(), bg_cpu = in.background.cpu();
  // The chain rule runs once per pass of up to kChainViews views with
  // triangles (whole bin groups: a group's gradient rows are its list's).
  // The pass's per-triangle screen gradients are one buffer, its groups'
  // lists one after another, with a row map per view; launch_chain resets
  // both, so they are set once, as large as the largest pass.
  const std::vector<SavedGroup> groups = saved_groups(views, V);
  int64_t rows = 0;
  {
    int slots = 0;
    int64_t pass_rows = 0;
    for (const SavedGroup& b : groups) {
      if (b.live == 0) continue;
      if (slots + b.live > kChainViews) slots = 0, pass_rows = 0;
      slots += b.live;
      pass_rows += b.rows;
      rows = std::max(rows, pass_rows);
    }
  }
  const at::Tensor tri_grads = at::zeros({rows * kTriGradStride}, f);
  const at::Tensor row_of = at::full({kChainViews, N}, -1, f.dtype(at::kInt));
  ChainViews pass;
  pass.tri_grads = tri_grads.data_ptr<float>();
  int64_t pass_rows = 0;
  auto chain = [&] {
    launch_chain(in.vertices.data_ptr<float>(), N, pass, g.vertices.data_ptr<float>(), g.colors.data_ptr<float>(),
                 g.opacities.data_ptr<float>(), g.sigmas.data_ptr<float>(), stream);
    check_launch("preprocess backward");
    pass.count = 0;
    pass_rows = 0;
  };
  for (const SavedGroup& b : groups) {
    if (b.live == 0) continue;
    if (pass.count + b.live > kChainViews) chain();
    const ViewState first = ViewState::of(views, b.first_view);
    at::Tensor tris = first.screen;  // kept, or recomputed here
    if (tris.numel() == 0) {
      ScreenData sd(b.rows, false, f);
      for (int64_t v = b.first_view; v < b.first_view + b.views; ++v) {
        const at::Tensor& visible = ViewState::of(views, v).visible;
        sd.add(in, visible.data_ptr<int>(), visible.numel(), visible.storage_offset(),
               make_params(in, w2c_cpu, K_cpu, bg_cpu, v), nullptr, nullptr, stream);
      }
      tris = sd.tris;
    }
    // One compositing launch for the group's views: their ranges, tile orders
    // and per-pixel maps are slices of the group's tensors, view after view
    // from the first view's, and their images are consecutive.
    const int64_t v0 = b.first_view;
    FLAT_CHECK(b.views <= kBinViews, "rasterize (cuda): backward state has a bin group of more than 2 views");
    ViewParams vps[kBinViews];
    for (int j = 0; j < b.views; ++j) vps[j] = make_params(in, w2c_cpu, K_cpu, bg_cpu, v0 + j);
    const at::Tensor& masks = first.masks;
    BackwardImages img{grad_rgb.data_ptr<float>() + v0 * 3 * HW, grad_alpha.data_ptr<float>() + v0 * HW,
                       grad_depth.data_ptr<float>() + v0 * HW,  grad_normal.data_ptr<float>() + v0 * 3 * HW,
                       first.t_final.data_ptr<float>(),         first.last.data_ptr<int>(),
                       PairMasks{reinterpret_cast<uint32_t*>(masks.data_ptr<int>()), masks.numel() / 2}};
    launch_raster_backward(reinterpret_cast<const int2*>(first.ranges.data_ptr<int>()), first.tile_order.data_ptr<int>(),
                           first.ids_sorted.data_ptr<int>(), reinterpret_cast<const PixelTri<float>*>(tris.data_ptr<float>()),
                           vps[0], group_rays(vps, (int)b.views), img,
                           pass.tri_grads + pass_rows * kTriGradStride,  // rows of the group's list
                           stream);
    check_launch("backward rasterization");
    for (int j = 0; j < b.views; ++j) {
      const at::Tensor visible = ViewState::of(views, v0 + j).visible;
      if (visible.numel() == 0) continue;
      const int slot = pass.count++;
      pass.cam[slot] = vps[j].cam;
      pass.row_of[slot] = row_of[slot].data_ptr<int>();
      launch_row_map(visible.data_ptr<int>(), visible.numel(), (int32_t)(pass_rows + visible.storage_offset()),
                     pass.row_of[slot], stream);
      check_launch("row map");
    }
    pass_rows += b.rows;
  }
  if (pass.count > 0) chain();
  return g;
}

}  // namespace flat::render::cuda
