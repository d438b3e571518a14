// The camera of one view and the pixels a primitive's support covers, as the
// three rasterizers (triangles, 3DGS, 2DGS) read them in their CPU
// references and CUDA kernels. Plain C++ with __host__ __device__ under nvcc.
// Public, under flat/render/shared/, because gaussians and surfels include it.
#pragma once
#include <cmath>
#include <cstdint>

#include "flat/render/shared/compositing.h"

namespace flat::render {

template <class T>
struct CameraView {
  T R[9];  // world-to-camera rotation, row-major
  T t[3];
  T fx, fy, cx, cy;  // pixels
};

// From a row-major 4x4 world-to-camera matrix and pixel intrinsics fx, fy, cx, cy.
template <class T>
FLAT_HD CameraView<T> make_camera_view(const T* w2c, const T* K) {
  CameraView<T> cam;
  for (int r = 0; r < 3; ++r) {
    for (int c = 0; c < 3; ++c) cam.R[3 * r + c] = w2c[4 * r + c];
    cam.t[r] = w2c[4 * r + 3];
  }
  cam.fx = K[0], cam.fy = K[1], cam.cx = K[2], cam.cy = K[3];
  return cam;
}

// What a CUDA tile kernel reads of one view, whatever its primitive: the
// camera, the constants K (CompositingConstants for 3DGS and 2DGS, the
// triangles' RasterConstants), the image and its tiles, the background.
template <class K>
struct TileView {
  CameraView<float> cam;
  K k;
  int width = 0, height = 0;
  int tiles_x = 0, tiles_y = 0;
  float background[3] = {0.f, 0.f, 0.f};
};

// On the host, from a row-major 4x4 world-to-camera matrix, pixel intrinsics
// fx, fy, cx, cy and the background colour (3), for tiles of tile_size pixels.
template <class K>
TileView<K> make_tile_view(const float* w2c, const float* intrinsics, const K& k, int64_t width, int64_t height,
                           int tile_size, const float* background) {
  TileView<K> v;
  v.cam = make_camera_view(w2c, intrinsics);
  v.k = k;
  v.width = (int)width;
  v.height = (int)height;
  v.tiles_x = (int)((width + tile_size - 1) / tile_size);
  v.tiles_y = (int)((height + tile_size - 1) / tile_size);
  for (int c = 0; c < 3; ++c) v.background[c] = background[c];
  return v;
}

// Pixels [x0,x1) x [y0,y1): a primitive's support in one view. The CPU
// references shade exactly these pixels; the CUDA binning gives it the tiles
// they touch.
struct PixelRect {
  int x0, y0, x1, y1;
};

// The pixels whose centres (x + 0.5, y + 0.5) lie in the box [lo, hi] (pixel
// units; unbounded or NaN-free bounds are clamped before the int conversion),
// within the image. Returns false when there is none.
template <class T>
FLAT_HD bool covered_pixels(const T lo[2], const T hi[2], int width, int height, PixelRect& rect) {
  const T big = T(1 << 24);
  const T fx0 = std::ceil(tmax(tmin(lo[0] - T(0.5), big), -big));
  const T fx1 = std::floor(tmax(tmin(hi[0] - T(0.5), big), -big)) + T(1);
  const T fy0 = std::ceil(tmax(tmin(lo[1] - T(0.5), big), -big));
  const T fy1 = std::floor(tmax(tmin(hi[1] - T(0.5), big), -big)) + T(1);
  rect.x0 = (int)tmax(fx0, T(0));
  rect.y0 = (int)tmax(fy0, T(0));
  rect.x1 = (int)tmin(fx1, T(width));
  rect.y1 = (int)tmin(fy1, T(height));
  return rect.x0 < rect.x1 && rect.y0 < rect.y1;
}

}  // namespace flat::render
