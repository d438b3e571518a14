// What flat_infer decodes: one window of precomputed latents with the cameras
// of its frames, from either
//   a scene folder (scene.json + latents.safetensors, data/scene_latents.h):
//     window i of its latents and the cameras of the frames it covers; or
//   a latent file plus a trajectory (cameras JSON, camera/camera_json.h):
//     "video" (16,T',h,w) or (1,16,T',h,w), normalised Wan 2.1 latents, and
//     optionally "camera" (32,T',h,w) RPPC camera latents; without them they
//     are encoded from the trajectory with the Wan VAE encoder (vae_weights).
// The trajectory must have T = 1 + 4(T'-1) cameras; any T' works (long
// inputs go through the streaming decoder).
#pragma once
#include <cstdint>
#include <string>

#include "flat/camera/cameras.h"
#include "flat/pipeline/scene_pipeline.h"

namespace flat::infer {

struct InputSpec {
  std::string scene_dir;  // a scene folder, or ""
  int64_t window = 0;     // which latent window of the scene
  std::string latent_set;  // which latent set ("176x320_f17"; "" = the scene's only one)
  std::string latents_file, cameras_file;
  std::string vae_weights;  // Wan VAE weights to encode missing camera latents ("" = none)
  bool need_camera_latents = true;  // the model has a camera adapter
  std::string camera_rays = "rppc";  // which camera latents the model reads (pipeline.model.camera_rays)
};

struct InferInput {
  pipeline::SceneInput input;  // B = 1, on the CPU
  camera::Cameras cameras;     // the T input cameras (CPU, float32)
  int64_t height = 0, width = 0;  // frame size: 8x the latent's
  std::string label;              // "scene room_000001, window 0" / the latent file
  // How the latents were made: "pretrained", "random" (a random-weight
  // encoder: the output is a pipeline check, not a result) or "unknown".
  std::string latent_encoder = "unknown";
};

// Throws flat::Error naming the file and shapes on any mismatch.
InferInput load_infer_input(const InputSpec& spec);

}  // namespace flat::infer
