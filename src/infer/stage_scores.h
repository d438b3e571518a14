// flat_mesh's scoreboard (mesh_run.h): each stage's soup (feedforward,
// refined, mesh) rendered into every view of the window and scored on the
// fitted and the held-out views, beside the baselines a result must beat.
#pragma once
#include <cstdint>
#include <string>
#include <vector>

#include <nlohmann/json.hpp>
#include <torch/torch.h>

#include "flat/data/scene.h"
#include "flat/infer/mesh_run.h"
#include "flat/mesh/refine.h"
#include "infer/mesh_inputs.h"

namespace flat::infer {

struct Rendered {
  at::Tensor rgb, normal, alpha;  // CPU, every view
};

// Frames of other scenes for the baselines (undefined when none).
struct Baselines {
  at::Tensor dataset_mean;  // (V,3,H,W): the other scenes' frames averaged per view
  at::Tensor swap;          // (V,3,H,W): the first other scene's frames
};

// The same window of each of `scene_dirs` (the scene itself skipped); each
// must match `views` in frame count and size, else flat::Error names it.
Baselines load_baselines(const std::vector<std::string>& scene_dirs, const data::Scene& scene,
                         const MeshSource& source, const mesh::ViewTargets& views);

// Scores as metrics.json holds them (NaN as null).
nlohmann::json to_json(const ViewScores& s);

class StageScorer {
 public:
  // An empty `lpips` scores no LPIPS; views are rendered `chunk` at a time.
  StageScorer(const mesh::ViewTargets& views, const ViewSplit& split, loss::Lpips lpips, Baselines baselines,
              int64_t chunk);

  // Renders `soup`, puts its fitted and held-out scores under summary.scores[name]
  // and logs them.
  void add(const std::string& name, const primitives::TriangleSoup& soup, const render::RasterSettings& raster,
           MeshRunSummary& summary);

  const std::vector<Rendered>& stages() const { return stages_; }

 private:
  const mesh::ViewTargets& views_;
  const ViewSplit& split_;
  loss::Lpips lpips_;
  Baselines baselines_;
  int64_t chunk_;
  std::vector<Rendered> stages_;
};

}  // namespace flat::infer
