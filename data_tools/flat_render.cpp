// flat_render: render a triangle soup (PLY, docs/formats.md) into every camera
// of a cameras JSON: RGB, alpha, depth and normals, as images or safetensors.
// The output folder appears whole or not at all; an existing one is kept
// unless --overwrite.
#include <filesystem>

#include <CLI/CLI.hpp>
#include <spdlog/spdlog.h>
#include <torch/torch.h>

#include "flat/camera/camera_json.h"
#include "flat/core/cli.h"
#include "flat/core/error.h"
#include "flat/core/image_io.h"
#include "flat/core/progress.h"
#include "flat/core/staged_dir.h"
#include "flat/core/tensor_io.h"
#include "flat/export/triangle_ply.h"
#include "flat/render/rasterize.h"

namespace {

// --background r,g,b: three finite numbers in [0,1], else a usage error (exit 2).
std::vector<double> parse_rgb(const std::string& text) {
  const std::string bad = "flat_render: --background must be three numbers r,g,b in [0,1], got '" + text + "'";
  std::vector<double> v;
  std::stringstream ss(text);
  std::string item;
  while (std::getline(ss, item, ',')) {
    size_t used = 0;
    double x = 0;
    try {
      x = std::stod(item, &used);
    } catch (const std::exception&) {
      throw flat::cli::UsageError(bad);
    }
    if (used != item.size() || !(x >= 0.0 && x <= 1.0)) throw flat::cli::UsageError(bad);  // NaN fails too
    v.push_back(x);
  }
  if (v.size() != 3) throw flat::cli::UsageError(bad);
  return v;
}

int run(int argc, char** argv) {
  CLI::App app{"flat_render: render a triangle soup into cameras (RGB, alpha, depth, normals)"};
  std::string ply, cams_path, out_dir, format = "safetensors", window = "flat", background = "0,0,0", device = "auto";
  std::string log_level = "info";
  bool overwrite = false;
  double eps = flat::render::RasterSettings{}.eps;
  flat::cli::add_common(app, "flat_render", log_level);
  app.add_option("--triangles", ply, "triangle soup PLY (docs/formats.md)")->required()->check(CLI::ExistingFile);
  app.add_option("--cameras", cams_path, "cameras JSON (docs/formats.md)")->required()->check(CLI::ExistingFile);
  app.add_option("--out", out_dir, "output folder (must not exist unless --overwrite)")->required();
  app.add_flag("--overwrite", overwrite, "replace an existing output folder (only once the new one is complete)");
  app.add_option("--format", format, "output format: png | exr | safetensors (png: rgb/alpha 8-bit, depth/normal need exr)")
      ->check(CLI::IsMember({"png", "exr", "safetensors"}));
  flat::cli::add_window_fn(app, window);
  flat::cli::add_old_name(app, "--window", "--window-fn");
  app.add_option("--eps", eps, "FLAT window support beyond each edge, in inradii")->check(CLI::Range(0.0, 1.0));
  app.add_option("--background", background, "background colour r,g,b in [0,1]");
  flat::cli::add_device(app, device);
  int threads = 0;
  flat::cli::add_threads(app, threads);
  if (int rc = flat::cli::parse(app, argc, argv); rc >= 0) return rc;
  flat::cli::apply_threads(threads);
  flat::render::RasterSettings settings;
  settings.background = parse_rgb(background);
  std::string log = out_dir;
  while (log.size() > 1 && log.back() == '/') log.pop_back();
  flat::cli::start_logging(log_level, log + ".log");
  settings.window = window;
  settings.eps = eps;
  settings.check();
  const torch::Device dev = flat::cli::resolve_device(device);
  flat::StagedDir staged(out_dir, overwrite);  // refuses an existing folder before any work

  const auto soup = flat::exporter::read_triangle_ply(ply);
  const auto set = flat::camera::read_cameras_json(cams_path);
  spdlog::info("{}: {} triangles; {}: {} cameras at {}x{}", ply, soup.vertices.size(0), cams_path, set.cameras.size(),
               set.width, set.height);
  const int64_t V = set.cameras.size();
  // Every view's RGB, alpha, depth and normals (8 floats a pixel) are kept on the host;
  // one view's buffers (a few times that) on the device.
  const double pixels = double(set.height) * double(set.width);
  flat::cli::check_memory(double(V) * pixels * 8.0 * 4.0, "flat_render: " + std::to_string(V) + " views at " +
                          std::to_string(set.width) + "x" + std::to_string(set.height), c10::Device(c10::kCPU));
  flat::cli::check_memory(pixels * 8.0 * 4.0 * 4.0, "flat_render: one view at " + std::to_string(set.width) + "x" +
                          std::to_string(set.height), dev);
  torch::NoGradGuard no_grad;
  auto v = soup.vertices.to(dev), c = soup.colors.to(dev), o = soup.opacities.to(dev), s = soup.sigmas.to(dev);
  flat::Progress progress("render", V);
  std::vector<torch::Tensor> rgb, alpha, depth, normal;
  for (int64_t i = 0; i < V; ++i) {  // one view at a time keeps memory flat for long trajectories
    auto cam = set.cameras.index(torch::tensor({i}, torch::kLong)).to(dev);
    auto r = flat::render::rasterize(v, c, o, s, cam, set.height, set.width, settings);
    rgb.push_back(r.rgb.cpu());
    alpha.push_back(r.alpha.cpu());
    depth.push_back(r.depth.cpu());
    normal.push_back(r.normal.cpu());
    progress.step();
  }
  progress.finish();
  const auto out = std::filesystem::path(staged.path());
  if (format == "safetensors") {
    flat::save_safetensors((out / "render.safetensors").string(),
                           {{"rgb", torch::cat(rgb)}, {"alpha", torch::cat(alpha)}, {"depth", torch::cat(depth)},
                            {"normal", torch::cat(normal)}},
                           {{"window", window}, {"eps", std::to_string(eps)}, {"triangles", ply}, {"cameras", cams_path},
                            {"depth", "alpha-weighted expected depth (divide by alpha for metric depth)"}});
    staged.commit();
    spdlog::info("wrote {}", (std::filesystem::path(out_dir) / "render.safetensors").string());
    return 0;
  }
  for (int64_t i = 0; i < V; ++i) {
    char stem[32];
    std::snprintf(stem, sizeof(stem), "%04lld", (long long)i);
    const std::string base = (out / stem).string();
    if (format == "png") {
      flat::write_image(base + "_rgb.png", rgb[i][0]);
      flat::write_image(base + "_alpha.png", alpha[i][0]);
      // Normals mapped from [-1,1] to [0,1] for viewing; depth needs exr or safetensors.
      flat::write_image(base + "_normal.png", normal[i][0] * 0.5 + 0.5);
    } else {
      flat::write_image(base + "_rgb.exr", rgb[i][0]);
      flat::write_image(base + "_alpha.exr", alpha[i][0]);
      flat::write_image(base + "_depth.exr", depth[i][0]);
      flat::write_image(base + "_normal.exr", normal[i][0]);
    }
  }
  staged.commit();
  spdlog::info("wrote {} views to {}", V, out_dir);
  return 0;
}

}  // namespace

int main(int argc, char** argv) {
  return flat::cli::run([&] { return run(argc, argv); });
}
