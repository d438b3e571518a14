#include "flat/data/pack.h"

#include <filesystem>

#include "flat/core/error.h"
#include "flat/core/tensor_io.h"
#include "flat/data/scene_frames.h"

namespace flat::data {

void pack_scene(Scene& scene, bool remove_frame_files) {
  FLAT_CHECK(scene.packed.empty() || !remove_frame_files || !scene.frames[0].image.empty(),
             scene.json_path() + ": scene is already packed without frame files");
  TensorMap tensors;
  std::vector<at::Tensor> rgb, depth, normals;
  // Frame by frame, so only one decoded frame is held in float at a time.
  for (int64_t i = 0; i < scene.size(); ++i) {
    FrameBatch f = load_frames(scene, {i}, scene.has_depth, scene.has_normals);
    rgb.push_back((f.images[0].clamp(0, 1) * 255).round().to(at::kByte));
    if (scene.has_depth) depth.push_back(f.depth[0]);
    if (scene.has_normals) normals.push_back(f.normals[0].to(at::kHalf));
  }
  tensors["images"] = at::stack(rgb);
  if (scene.has_depth) tensors["depth"] = at::stack(depth);
  if (scene.has_normals) tensors["normals"] = at::stack(normals);
  save_safetensors(scene.path(kPackFile), tensors,
                   {{"format", "flat-scene-pack"}, {"version", "1"}, {"scene", scene.name}});
  Scene old = scene;
  scene.packed = kPackFile;
  if (remove_frame_files)
    for (auto& f : scene.frames) f.image = f.depth = f.normals = "";
  write_scene_json(scene);
  if (remove_frame_files)
    for (const auto& f : old.frames)
      for (const auto* rel : {&f.image, &f.depth, &f.normals})
        if (!rel->empty()) std::filesystem::remove(old.path(*rel));
}

}  // namespace flat::data
