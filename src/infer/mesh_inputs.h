// What flat_mesh fits (mesh_run.h): the soup and the scene window it was
// decoded from, that window's frames as targets, and which of them are held
// out.
#pragma once
#include <cstdint>
#include <string>

#include <torch/torch.h>

#include "flat/data/scene.h"
#include "flat/infer/mesh_run.h"
#include "flat/mesh/view_targets.h"
#include "flat/primitives/triangle_soup.h"

namespace flat::infer {

struct MeshSource {
  primitives::TriangleSoup soup;
  std::string scene_dir;
  int64_t window = -1;
  std::string latent_set;  // "" = the scene's only set
};

// The soup, and the scene window it came from: flat_infer's summary.json
// beside it, overridden by the options; throws flat::Error naming the file.
MeshSource read_mesh_source(const MeshRunOptions& o);

// The window's frames at the soup's frame size (the latents' size).
mesh::ViewTargets load_window_targets(const data::Scene& scene, int64_t window, bool depth, bool normals);

struct ViewSplit {
  at::Tensor fitted, held_out;  // (K,) int64 view indices
};

// Every `every`-th view, from the middle of the first group on, is held out
// (none when every <= 1).
ViewSplit split_views(int64_t views, int64_t every);

}  // namespace flat::infer
