// rasterize_surfels(): the splat rasterizers' checks, dispatch and autograd
// Function (flat/render/shared/splat_function.h) over the surfels' CPU
// reference and CUDA kernels.
#include "flat/surfels/rasterize_surfels.h"

#include "flat/render/shared/splat_function.h"
#include "surfels/cpu/raster_surfels_cpu.h"
#if FLAT_WITH_CUDA
#include "surfels/cuda/raster_surfels_cuda.h"
#endif

namespace flat::surfels {

static_assert(kDistortionNear == kNdcNear && kDistortionFar == kNdcFar,
              "the kernels' NDC range is the header's");

namespace {

// The values are checked before the call (a sync on the GPU).
constexpr render::SplatKind kKind{"rasterize_surfels", /*scale_dims=*/2, /*normal=*/true, /*distortion=*/true,
                                  /*cuda_checks_values=*/false};
#if FLAT_WITH_CUDA
using Function = render::SplatFunction<kKind, cpu::forward, cpu::backward, cuda::forward, cuda::backward>;
#else
using Function = render::SplatFunction<kKind, cpu::forward, cpu::backward>;  // CUDA inputs fail
#endif

}  // namespace

render::RenderOutput rasterize_surfels(const at::Tensor& means, const at::Tensor& scales, const at::Tensor& rotations,
                                       const at::Tensor& colors, const at::Tensor& opacities,
                                       const camera::Cameras& cams, int64_t height, int64_t width,
                                       const render::CompositingSettings& settings) {
  return Function::rasterize(means, scales, rotations, colors, opacities, cams, height, width, settings);
}

}  // namespace flat::surfels
