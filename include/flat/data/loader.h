// Training data loader (paper, Model Training / Training Details): samples a
// dataset by weight, a scene uniformly, an input window of F frames and V
// target views half seen / half unseen (view_sampler.h); loads the target
// frames (RGB, depth, normals), resizes them to the stage resolution
// (intrinsics follow), and the precomputed latents of the window when asked.
// Batches are deterministic for a seed (batch b depends only on seed and b),
// whatever the number of prefetch threads. Bad scenes (missing or corrupt
// files) either fail with the scene and file named or, with skip_bad_scenes,
// are skipped, counted and logged.
#pragma once
#include <atomic>
#include <condition_variable>
#include <cstdint>
#include <exception>
#include <map>
#include <memory>
#include <mutex>
#include <set>
#include <string>
#include <thread>
#include <vector>

#include <ATen/ATen.h>

#include "flat/camera/cameras.h"
#include "flat/core/config.h"
#include "flat/data/scene.h"
#include "flat/data/view_sampler.h"

namespace flat::data {

// One dataset: a folder of scene folders (or a single scene folder) and its mixing weight.
struct DatasetSource {
  std::string root;
  double weight = 1.0;
  template <class V>
  void visit(V& v) {
    v.required("root", root, "folder of scene folders (or one scene folder)");
    v.field("weight", weight, config::non_negative(), "mixing weight (relative)");
  }
};

struct LoaderConfig {
  std::vector<DatasetSource> datasets;
  int64_t height = 176;  // stage resolution of the loaded frames (stage 1: 320p)
  int64_t width = 320;
  int64_t input_frames = 17;  // F: 17 (stage 1) or 49 (stages 2-4)
  int64_t target_views = 17;  // V: 17, 49, 49, 24
  double unseen_fraction = 0.5;
  int64_t frame_stride = 1;
  int64_t unseen_max_gap = 0;
  int64_t batch_size = 1;
  int64_t workers = 2;   // prefetch threads (0 = load in the calling thread)
  int64_t prefetch = 4;  // batches loaded ahead
  int64_t seed = 0;
  bool depth = true;          // load target depth where the scene has it
  bool normals = true;        // load target normals where the scene has it
  bool input_images = false;  // also load the F input frames (for on-the-fly encoding)
  bool latents = false;       // require and load the window's precomputed latents
  bool skip_bad_scenes = false;
  // What a dataset that loses scenes does: "warn" logs each dataset's count
  // and reasons; "fail" stops the run when any scene lacks this stage's latent
  // set or any dataset with a positive weight is left with no scene (a mixture
  // never changes silently). Scenes too short for the window are only logged.
  std::string incomplete_datasets = "warn";
  // Not a YAML key: the trainer copies pipeline.model.camera_rays here, so the
  // loader reads the camera latents the model is conditioned on.
  std::string camera_rays = "rppc";

  template <class V>
  void visit(V& v) {
    v.list("datasets", datasets);
    v.field("height", height, config::positive(), "frame height after resizing");
    v.field("width", width, config::positive(), "frame width after resizing");
    v.field("input_frames", input_frames, config::positive(), "input window F (1+4k)");
    v.field("target_views", target_views, config::positive(), "target views V");
    v.field("unseen_fraction", unseen_fraction, config::range(0, 1), "share of targets outside the window");
    v.field("frame_stride", frame_stride, config::positive(), "step between window frames");
    v.field("unseen_max_gap", unseen_max_gap, config::non_negative(), "max distance of unseen targets (0 = any)");
    v.field("batch_size", batch_size, config::positive(), "scenes per batch");
    v.field("workers", workers, config::non_negative(), "prefetch threads");
    v.field("prefetch", prefetch, config::positive(), "batches loaded ahead");
    v.field("seed", seed, "sampling seed");
    v.field("depth", depth, "load target depth");
    v.field("normals", normals, "load target normals");
    v.field("input_images", input_images, "load the input window frames");
    v.field("latents", latents, "load precomputed latents (scenes without them are bad)");
    v.field("skip_bad_scenes", skip_bad_scenes, "skip and count bad scenes instead of failing");
    v.field("incomplete_datasets", incomplete_datasets, config::one_of({"warn", "fail"}),
            "warn | fail: when scenes lack this stage's latent set, or a dataset of the mixture has no usable "
            "scene, log it per dataset (warn) or stop (fail)");
  }
  void check() const;  // cross-field checks (F = 1+4k, at least one dataset with weight > 0)
  ViewSamplerConfig views() const;
};

// What the loader found in one dataset: how many scenes it uses and why it left
// out the rest (logged, and written to the run folder by the trainer).
struct DatasetReport {
  std::string root;
  double weight = 0;
  int64_t found = 0;       // scene folders
  int64_t used = 0;
  int64_t short_scenes = 0;      // fewer frames than one window of the stage
  int64_t missing_set = 0;       // long enough, but without this stage's latent set
  int64_t bad = 0;               // unreadable scene.json (skip_bad_scenes)
  int64_t with_depth = 0, with_normals = 0;  // among the used scenes
  std::map<std::string, int64_t> other_sets;  // latent sets the missing_set scenes hold instead
  std::string example_missing;                // one such scene, for the message
};

struct Sample {
  std::string scene;                    // scene name
  std::string scene_dir;
  std::vector<int64_t> input_frames;    // F
  std::vector<int64_t> target_frames;   // V
  at::Tensor target_seen;               // (V,) bool
  camera::Cameras input_cameras;        // F, intrinsics for the resized frames
  camera::Cameras target_cameras;       // V
  at::Tensor input_images;              // (F,3,H,W) or undefined
  at::Tensor target_images;             // (V,3,H,W)
  at::Tensor target_depth;              // (V,1,H,W) or undefined (scene without depth)
  at::Tensor target_normals;            // (V,3,H,W) or undefined
  at::Tensor video_latent;              // (16,T',h,w) or undefined
  at::Tensor camera_latent;             // (32,T',h,w) or undefined
};

// B samples stacked. Depth/normals of scenes without them are zeros with
// depth_present/normals_present false.
struct Batch {
  std::vector<std::string> scenes;
  at::Tensor input_frames, target_frames;  // (B,F), (B,V) int64
  at::Tensor target_seen;                  // (B,V) bool
  at::Tensor input_intrinsics, input_c2w;  // (B,F,4), (B,F,4,4)
  at::Tensor target_intrinsics, target_c2w;
  at::Tensor input_images;                 // (B,F,3,H,W) or undefined
  at::Tensor target_images;                // (B,V,3,H,W)
  at::Tensor target_depth;                 // (B,V,1,H,W) or undefined (depth off)
  at::Tensor target_normals;               // (B,V,3,H,W) or undefined
  at::Tensor depth_present, normals_present;  // (B,) bool
  at::Tensor video_latents, camera_latents;   // (B,16,T',h,w), (B,32,T',h,w) or undefined
  camera::Cameras input_cameras(int64_t b) const { return {input_intrinsics[b], input_c2w[b]}; }
  camera::Cameras target_cameras(int64_t b) const { return {target_intrinsics[b], target_c2w[b]}; }
};

Batch collate(const std::vector<Sample>& samples);

// Data-parallel and resumable: rank r of world_size W reads, as its batch b,
// the samples (b*W + r)*B .. (b*W + r)*B + B-1 of the stream, so the ranks
// never share a sample and together they read what one process with batch
// W*B would; next() starts at start_batch (the step a resumed run continues at).
class Loader {
 public:
  explicit Loader(LoaderConfig config, int64_t start_batch = 0, int64_t rank = 0, int64_t world_size = 1);
  ~Loader();
  Loader(const Loader&) = delete;
  Loader& operator=(const Loader&) = delete;

  // The next batch (0, 1, 2, ...), from the prefetch threads when workers > 0.
  Batch next();
  // Batch `index` of this rank, computed in the calling thread (same content as next() gives for it).
  Batch batch(int64_t index);
  // Sample `index` of the stream (batch b holds samples b*B .. b*B+B-1).
  Sample sample(int64_t index);

  int64_t scene_count() const;
  // Scenes by how their latents were made ("pretrained", "random"; "none"
  // without latents): provenance for logs, so that a figure trained or
  // scored on random-encoder latents never passes for a result.
  std::map<std::string, int64_t> latent_encoders() const;
  int64_t skipped_scenes() const { return skipped_; }
  const std::vector<DatasetReport>& reports() const { return reports_; }
  // Scenes carrying depth / normals among the used ones (all datasets).
  int64_t scenes_with_depth() const;
  int64_t scenes_with_normals() const;
  int64_t next_batch_index() const { return next_give_; }
  const LoaderConfig& config() const { return config_; }

 private:
  struct Dataset {
    std::string root;
    double weight = 1;
    std::vector<std::shared_ptr<const Scene>> scenes;
  };
  LoaderConfig config_;
  int64_t rank_ = 0, world_size_ = 1;
  std::vector<Dataset> datasets_;
  std::vector<double> cumulative_;  // normalised cumulative weights
  std::vector<DatasetReport> reports_;

  std::mutex bad_mutex_;
  std::set<std::string> bad_;  // scene dirs found bad
  std::atomic<int64_t> skipped_{0};
  void mark_bad(const std::string& dir, const std::string& why);
  bool is_bad(const std::string& dir);

  Sample load_sample(const Scene& scene, std::mt19937_64& rng) const;

  // Prefetch state.
  std::mutex mutex_;
  std::condition_variable ready_cv_, space_cv_;
  std::map<int64_t, Batch> ready_;
  std::map<int64_t, std::exception_ptr> failed_;
  int64_t next_claim_ = 0, next_give_ = 0;
  bool stop_ = false;
  std::vector<std::thread> threads_;
  void worker();
};

}  // namespace flat::data
