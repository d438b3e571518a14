// bin_rects(): the shared binning (tile_binning.h) of one view, or a chunk of
// views, of rectangle footprints, with its scratch allocated through libtorch.
#include "flat/render/shared/tile_lists.h"

#include <algorithm>
#include <string>

#include "flat/core/error.h"
#include "flat/render/shared/tile_binning.h"

namespace flat::render::cuda {

TileLists bin_rects(const RectFootprints& fp, int64_t pairs, int tile_size, int tiles_x, int tiles_y, int views,
                    const at::TensorOptions& opts, cudaStream_t stream, const char* fn) {
  auto check = [&](const char* what) {
    const cudaError_t err = cudaGetLastError();
    if (err != cudaSuccess) fail(std::string(fn) + " (cuda): " + what + " failed: " + cudaGetErrorString(err));
  };
  FLAT_CHECK(views >= 1 && (views == 1 || fp.per_view * views == fp.n),
             std::string(fn) + " (cuda): binning " + std::to_string(views) + " views of " +
                 std::to_string(fp.per_view) + " elements, but " + std::to_string(fp.n) + " elements");
  const int view_tiles = tiles_x * tiles_y;
  FLAT_CHECK(int64_t(view_tiles) * views < (int64_t(1) << 31),
             std::string(fn) + " (cuda): " + std::to_string(views) + " views of " + std::to_string(view_tiles) +
                 " tiles: more tile ids than 2^31");
  const int tiles = view_tiles * views;
  const int64_t n = fp.n;
  const auto i32 = opts.dtype(at::kInt);
  auto u32 = [](const at::Tensor& t) { return reinterpret_cast<uint32_t*>(t.data_ptr<int>()); };
  TileLists out;
  out.ranges = at::zeros({tiles, 2}, i32);
  out.ids = at::empty({pairs}, i32);
  if (pairs == 0) return out;
  size_t depth_bytes = 0, scan_bytes = 0, tile_bytes = 0;
  sort_by_depth(nullptr, depth_bytes, nullptr, nullptr, nullptr, nullptr, n, stream);
  scan_counts(nullptr, scan_bytes, nullptr, nullptr, n, stream);
  sort_by_tile(nullptr, tile_bytes, nullptr, nullptr, nullptr, nullptr, pairs, tiles, stream);
  const at::Tensor temp = at::empty({(int64_t)std::max({depth_bytes, scan_bytes, tile_bytes}) + 1}, opts.dtype(at::kByte));
  const at::Tensor order = at::empty({n}, i32), order_sorted = at::empty({n}, i32), depth_sorted = at::empty({n}, i32);
  const at::Tensor counts = at::empty({n}, i32), offsets = at::empty({n}, i32);
  const at::Tensor pair_tiles = at::empty({pairs}, i32), tiles_sorted = at::empty({pairs}, i32);
  const at::Tensor pair_ids = at::empty({pairs}, i32);
  launch_iota(order.data_ptr<int>(), n, stream);
  sort_by_depth(temp.data_ptr(), depth_bytes, fp.depth_keys, u32(depth_sorted), order.data_ptr<int>(),
                order_sorted.data_ptr<int>(), n, stream);
  check("depth sort");
  launch_gather_counts(order_sorted.data_ptr<int>(), n, fp.tile_counts, counts.data_ptr<int>(), stream);
  scan_counts(temp.data_ptr(), scan_bytes, counts.data_ptr<int>(), offsets.data_ptr<int>(), n, stream);
  check("tile count scan");
  launch_duplicate_rects(order_sorted.data_ptr<int>(), n, counts.data_ptr<int>(), offsets.data_ptr<int>(), fp.rects,
                         fp.masks, tile_size, tiles_x, views > 1 ? fp.per_view : 0, view_tiles, u32(pair_tiles),
                         pair_ids.data_ptr<int>(), stream);
  check("pair duplication");
  sort_by_tile(temp.data_ptr(), tile_bytes, u32(pair_tiles), u32(tiles_sorted), pair_ids.data_ptr<int>(),
               out.ids.data_ptr<int>(), pairs, tiles, stream);
  check("tile sort");
  launch_tile_ranges(u32(tiles_sorted), pairs, reinterpret_cast<int2*>(out.ranges.data_ptr<int>()), stream);
  check("tile ranges");
  return out;
}

}  // namespace flat::render::cuda
