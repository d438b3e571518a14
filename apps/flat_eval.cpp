// flat_eval: score a trained decoder on held-out scenes as the paper's Table 1
// (PSNR, SSIM, LPIPS; normal L1 and cosine), or put earlier runs side by side.
//
//   flat_eval --model runs/stage1 --scenes RE10K=data/re10k_test --scenes DL3DV=data/dl3dv_test --out eval/stage1
//   flat_eval --compare eval/stage1 eval/no_product_window --out-table ablation.md
//
// Resumable: run it again with the same --out and only unscored scenes are done.
// Exit codes: 0 done (scenes that failed are listed, and counted in the table),
// 1 runtime error or every scene failed, 2 usage error.
#include <iostream>

#include <CLI/CLI.hpp>

#include "flat/core/atomic_file.h"
#include "flat/core/cli.h"
#include "flat/core/cli_model_options.h"
#include "flat/core/config.h"
#include "flat/core/error.h"
#include "flat/core/log.h"
#include "flat/eval/evaluation_run.h"
#include "flat/pipeline/scene_pipeline.h"

int main(int argc, char** argv) {
  CLI::App app{"flat_eval: Table-1 metrics of a trained decoder over scene folders, or a comparison of runs"};
  app.get_formatter()->column_width(36);
  flat::eval::EvalRunOptions o;
  flat::cli::add_common(app, "flat_eval", o.log_level);
  std::vector<std::string> compare;
  std::string size, ssim = "skimage", out_table;
  bool full_sequence = false;
  app.add_option("--model", o.model, "run folder, checkpoint folder or model .safetensors");
  app.add_option("--scenes", o.datasets, "NAME=FOLDER (or FOLDER, or a list file); repeat per dataset")->take_all();
  app.add_option("--out", o.out_dir, "output folder (resumable; reuse it to continue)");
  app.add_option("--name", o.name, "the method's name in the table (default: the run folder's name)");
  // Checked at parse time: a bad value is a usage error (exit 2), not a failure of every scene.
  app.add_option("--views", o.settings.views, "scene | window | unseen")
      ->check(CLI::IsMember({"scene", "window", "unseen"}))
      ->capture_default_str();
  app.add_option("--max-views", o.settings.max_views, "at most this many views per scene, evenly spaced (0 = all)")
      ->check(CLI::NonNegativeNumber)
      ->capture_default_str();
  app.add_option("--latent-set", o.settings.latent_set,
                 "which latent set of each scene, HxW_fF (e.g. 176x320_f17; default: each scene's only set)");
  app.add_option("--window-index", o.settings.window, "which stored latent window of each scene decodes it (0: the first)")
      ->check(CLI::NonNegativeNumber)
      ->capture_default_str();
  flat::cli::add_old_name(app, "--window", "--window-index");
  app.add_option("--size", size, "render and compare at HxW (default: the latents' frame size)");
  app.add_option("--ssim", ssim, "skimage (Wang et al., as scikit-image) | 3dgs (the 3DGS repositories')")
      ->check(CLI::IsMember({"skimage", "3dgs"}))
      ->capture_default_str();
  app.add_option("--lpips-weights", o.lpips_weights, "LPIPS VGG weights (.safetensors, docs/losses.md)");
  int threads = 0;
  flat::cli::add_model_options(app, o.config, o.overrides, "pipeline.prune_opacity=0.4", o.device, threads,
                               o.precision);
  app.add_flag("--full-sequence", full_sequence, "decode all latent frames at once (default: streaming)");
  app.add_flag("--redo", o.redo, "score every scene again (also needed to reuse --out with other settings)");
  app.add_option("--compare", compare, "flat_eval output folders to put side by side (no --model)")->take_all();
  app.add_option("--out-table", out_table, "--compare: also write the Markdown table here");
  bool overwrite = false;
  app.add_flag("--overwrite", overwrite, "--compare: replace an existing --out-table file");
  if (int rc = flat::cli::parse(app, argc, argv); rc >= 0) return rc;
  flat::cli::apply_threads(threads);
  return flat::cli::run([&] {
    flat::setup_logging(o.log_level);
    // Full key paths, as flat_train's; the model's config is the pipeline section.
    o.overrides = flat::cli::section_overrides(o.overrides, "pipeline",
                                               flat::config::to_yaml(flat::pipeline::PipelineConfig{}), "flat_eval");
    if (!compare.empty()) {
      if (!o.model.empty() || !o.datasets.empty()) {
        std::cerr << "flat_eval: --compare reads earlier results; it takes no --model or --scenes\n";
        return 2;
      }
      // An existing table is refused before any work, unless --overwrite.
      if (!out_table.empty()) flat::check_output_file(out_table, overwrite, "--out-table");
      const auto table = flat::eval::compare_runs(compare);
      if (!out_table.empty()) flat::write_file_atomic(out_table, table);
      std::cout << table;
      return 0;
    }
    if (o.model.empty() || o.datasets.empty() || o.out_dir.empty()) {
      std::cerr << "flat_eval: give --model, --scenes and --out (or --compare FOLDERS...); see --help\n";
      return 2;
    }
    flat::cli::parse_size_option(size, o.settings.height, o.settings.width, "flat_eval");
    // Refused up front, not by the allocator of every scene: the rasterizer's limit is 2^30 pixels a view.
    if (!size.empty() && o.settings.height * o.settings.width > (int64_t(1) << 30)) {
      std::cerr << "flat_eval: --size " << size << " is " << o.settings.height * o.settings.width
                << " pixels a view, more than the rasterizer's 2^30\n";
      return 2;
    }
    o.settings.ssim = flat::eval::parse_ssim_convention(ssim);
    o.settings.streaming = !full_sequence;
    auto s = flat::eval::run_evaluation(o);
    std::cout << s.table << "\n"
              << "flat_eval: " << s.scenes << " scenes: " << s.scored << " scored now, " << s.reused
              << " reused from earlier runs, " << s.failed << " failed -> " << s.out_dir
              << "/{table.md,results.json,scenes.csv}\n";
    return s.failed == s.scenes ? 1 : 0;
  });
}
