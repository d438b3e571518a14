// rasterize_gaussians(): the splat rasterizers' checks, dispatch and autograd
// Function (flat/render/shared/splat_function.h) over the Gaussians' CPU
// reference and CUDA kernels.
#include "flat/gaussians/rasterize_gaussians.h"

#include "flat/render/shared/splat_function.h"
#include "gaussians/cpu/raster_gaussians_cpu.h"
#if FLAT_WITH_CUDA
#include "gaussians/cuda/raster_gaussians_cuda.h"
#endif

namespace flat::gaussians {
namespace {

// The CUDA back end checks the values at its first wait for the device.
constexpr render::SplatKind kKind{"rasterize_gaussians", /*scale_dims=*/3, /*normal=*/false, /*distortion=*/false,
                                  /*cuda_checks_values=*/true};
#if FLAT_WITH_CUDA
using Function = render::SplatFunction<kKind, cpu::forward, cpu::backward, cuda::forward, cuda::backward>;
#else
using Function = render::SplatFunction<kKind, cpu::forward, cpu::backward>;  // CUDA inputs fail
#endif

}  // namespace

render::RenderOutput rasterize_gaussians(const at::Tensor& means, const at::Tensor& scales, const at::Tensor& rotations,
                                         const at::Tensor& colors, const at::Tensor& opacities,
                                         const camera::Cameras& cams, int64_t height, int64_t width,
                                         const render::CompositingSettings& settings) {
  // normal and distortion stay undefined
  return Function::rasterize(means, scales, rotations, colors, opacities, cams, height, width, settings);
}

}  // namespace flat::gaussians
