#include "flat/model/camera_latents.h"

#include <torch/torch.h>

#include "flat/camera/ray_embeddings.h"
#include "flat/camera/rays.h"
#include "flat/core/error.h"
#include "flat/core/shape.h"
#include "flat/core/tensor_io.h"

namespace flat::model {

std::pair<at::Tensor, at::Tensor> ray_videos(const flat::camera::Cameras& cams, int64_t height, int64_t width,
                                             const std::string& rays) {
  cams.check("camera latents");
  FLAT_CHECK(rays == "rppc" || rays == "plucker", "camera latents: rays must be rppc or plucker, got '" + rays + "'");
  // (F,6,H,W) -> (1,6,F,H,W): the frames become the video's time axis.
  const auto pixel = flat::camera::pixel_rays(cams, height, width);
  at::Tensor map = rays == "plucker" ? flat::camera::plucker_map(pixel) : flat::camera::rppc_map(pixel);
  at::Tensor video = map.permute({1, 0, 2, 3}).unsqueeze(0);
  return {video.narrow(1, 0, 3).contiguous(), video.narrow(1, 3, 3).contiguous()};
}

at::Tensor encode_camera_latents(WanVAE& vae, const flat::camera::Cameras& cams, int64_t height, int64_t width,
                                 bool streaming, const std::string& rays) {
  latent_frames(cams.size(), "encode_camera_latents: " + std::to_string(cams.size()) + " cameras");
  FLAT_CHECK(height % 8 == 0 && width % 8 == 0, "encode_camera_latents: height and width must be multiples of 8, got " +
                                                    std::to_string(height) + "x" + std::to_string(width));
  torch::NoGradGuard no_grad;
  const at::Tensor probe = vae->conv2->weight;
  auto [ref, dir] = ray_videos(cams.to(probe.device()), height, width, rays);  // rays on the VAE's device
  // Both halves in one batch of 2 (one encoder pass), then side by side on channels.
  at::Tensor both = at::cat({ref, dir}, 0).to(probe.device(), probe.scalar_type());
  at::Tensor latents = vae->encode(both, streaming);
  return at::cat({latents.narrow(0, 0, 1), latents.narrow(0, 1, 1)}, 1);
}

void save_camera_latents(const std::string& path, const at::Tensor& latents, int64_t height, int64_t width) {
  check_shape(latents, {-1, 32, -1, -1, -1}, "save_camera_latents: " + path, "(B,32,T',h,w)");
  save_safetensors(path, {{"camera_latents", latents}},
                   {{"frames", std::to_string(video_frames(latents.size(2)))},
                    {"height", std::to_string(height)},
                    {"width", std::to_string(width)}});
}

at::Tensor load_camera_latents(const std::string& path) {
  return load_tensor_checked(path, "camera_latents", {-1, 32, -1, -1, -1}, "(B,32,T',h,w)");
}

}  // namespace flat::model
