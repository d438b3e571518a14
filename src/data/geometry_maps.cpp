// Depth and normals from external predictors (include/flat/data/geometry_maps.h).
#include "flat/data/geometry_maps.h"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <map>

#include <CLI/CLI.hpp>
#include <spdlog/spdlog.h>

#include "flat/core/error.h"
#include "flat/core/image_io.h"
#include "flat/core/npy.h"
#include "flat/core/shape.h"
#include "flat/data/frame_io.h"
#include "flat/data/frame_resize.h"
#include "flat/data/import_batch.h"

namespace flat::data {

namespace fs = std::filesystem;

namespace {

constexpr double kUnitTolerance = 0.05;     // float maps
constexpr double kUnitTolerancePng = 0.1;   // after decoding 0.5 n + 0.5 from 8 bits

std::string lower_extension(const std::string& path) {
  std::string ext = fs::path(path).extension().string();
  std::transform(ext.begin(), ext.end(), ext.begin(), [](unsigned char c) { return char(std::tolower(c)); });
  return ext;
}

std::string number(double v) {
  char buf[64];
  std::snprintf(buf, sizeof(buf), "%.6g", v);
  return buf;
}

// "640x480" (width x height, as image tools print sizes).
std::string size_str(int64_t height, int64_t width) { return std::to_string(width) + "x" + std::to_string(height); }

std::string pixel_str(int64_t flat_index, int64_t width) {
  return "(x=" + std::to_string(flat_index % width) + ", y=" + std::to_string(flat_index / width) + ")";
}

void check_size(const std::string& path, int64_t map_h, int64_t map_w, int64_t h, int64_t w, const std::string& image) {
  if (map_h != h || map_w != w)
    fail(path + ": map is " + size_str(map_h, map_w) + " but its frame's image " + image + " is " + size_str(h, w) +
         " (maps must have the source image's size)");
}

// (C,H,W): every value finite, else the count and the first pixel.
void check_finite_map(const at::Tensor& t, const std::string& path) {
  auto bad = at::logical_not(at::isfinite(t)).any(0).flatten();
  const int64_t n = bad.sum().item<int64_t>();
  if (n > 0)
    fail(path + ": " + std::to_string(n) + " pixels hold NaN or Inf (first at " +
         pixel_str(bad.nonzero()[0][0].item<int64_t>(), t.size(2)) + "); mark unknown pixels with 0");
}

struct PngInfo {
  int bit_depth = 0, color_type = 0;
};

// Bit depth and colour type from the IHDR chunk (read_image returns floats and hides them).
PngInfo png_info(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  unsigned char b[26] = {};
  in.read(reinterpret_cast<char*>(b), sizeof(b));
  static const unsigned char sig[8] = {0x89, 'P', 'N', 'G', '\r', '\n', 0x1a, '\n'};
  if (!in || std::memcmp(b, sig, 8) != 0 || std::memcmp(b + 12, "IHDR", 4) != 0)
    fail(path + ": not a PNG file");
  return {b[24], b[25]};
}

// A .npy map as (C,H,W) float32: depth (H,W) (1,H,W) (H,W,1), normals (H,W,3) (3,H,W);
// of several readings of the shape the one of the image's size.
at::Tensor npy_map(const std::string& path, bool normals, int64_t h, int64_t w, const std::string& image) {
  at::Tensor a = read_npy(path);
  if (!c10::isFloatingType(a.scalar_type()))
    fail(path + ": .npy dtype " + std::string(c10::toString(a.scalar_type())) +
         " is not supported for " + (normals ? "normals" : "depth") + " (float16, float32 or float64)");
  std::vector<at::Tensor> readings;
  if (!normals) {
    if (a.dim() == 2) readings.push_back(a.unsqueeze(0));
    if (a.dim() == 3 && a.size(0) == 1) readings.push_back(a);
    if (a.dim() == 3 && a.size(2) == 1) readings.push_back(a.permute({2, 0, 1}));
  } else {
    if (a.dim() == 3 && a.size(2) == 3) readings.push_back(a.permute({2, 0, 1}));
    if (a.dim() == 3 && a.size(0) == 3) readings.push_back(a);
  }
  if (readings.empty())
    fail(path + ": " + (normals ? "normals .npy must have shape (H,W,3) or (3,H,W)"
                                : "depth .npy must have shape (H,W), (1,H,W) or (H,W,1)") +
         ", got " + shape_str(a));
  for (const auto& r : readings)
    if (r.size(1) == h && r.size(2) == w) return r.to(at::kFloat).contiguous();
  check_size(path, readings[0].size(1), readings[0].size(2), h, w, image);
  return {};
}

// A depth file with several equal channels (grey saved as RGB) -> 1 channel.
at::Tensor one_channel(const at::Tensor& t, const std::string& path) {
  if (t.size(0) == 1) return t;
  if (t.size(0) >= 3 && at::equal(t[0], t[1]) && at::equal(t[0], t[2])) return t.narrow(0, 0, 1);
  fail(path + ": depth map has " + std::to_string(t.size(0)) + " channels; expected 1 (or grey RGB)");
}

// A (C,H,W) map on the image's undistorted pixel grid: each pixel takes the
// source pixel that holds its distorted position (nearest: floor of the
// position, pixel centres at +0.5); positions outside the map give 0 (unknown).
at::Tensor undistort_nearest(const at::Tensor& map, double fx, double fy, double cx, double cy, const Distortion& d) {
  const int64_t C = map.size(0), H = map.size(1), W = map.size(2);
  auto pos = distorted_positions(H, W, fx, fy, cx, cy, d);
  auto su = pos.select(-1, 0).floor(), sv = pos.select(-1, 1).floor();
  auto inside = (su >= 0) & (su < double(W)) & (sv >= 0) & (sv < double(H));
  auto index = (sv.clamp(0, double(H - 1)) * double(W) + su.clamp(0, double(W - 1))).to(at::kLong).flatten();
  auto out = map.reshape({C, H * W}).index_select(1, index).view({C, H, W});
  return at::where(inside.unsqueeze(0), out, at::zeros_like(out));
}

std::string join(const std::vector<std::string>& parts, const std::string& sep) {
  std::string out;
  for (const auto& p : parts) out += (out.empty() ? "" : sep) + p;
  return out;
}

void check_member(const std::string& value, const std::vector<std::string>& allowed, const std::string& what) {
  if (std::find(allowed.begin(), allowed.end(), value) == allowed.end())
    fail(what + " '" + value + "' is not one of " + join(allowed, ", "));
}

// --depth / --normals: a plain folder must exist. A batch pattern with {clip}
// is checked per clip as each is imported (import_batch.cpp); the folder above
// its first {clip} must exist now, so a typo there fails at once, not per clip.
CLI::Validator maps_folder(const std::string& what) {
  return CLI::Validator(
      [what](std::string& value) -> std::string {
        std::error_code ec;
        const auto at = value.find(kClipPlaceholder);
        if (at == std::string::npos)
          return fs::is_directory(value, ec) ? "" : value + ": no such folder (" + what + " maps)";
        const fs::path above = fs::path(value.substr(0, at)).parent_path();
        if (above.empty() || fs::is_directory(above, ec)) return "";
        return value + ": no such folder " + above.string() + " (the part above " + kClipPlaceholder + ")";
      },
      "DIR", "folder, or batch pattern with " + std::string(kClipPlaceholder));
}

// --<kind>, the folder of maps (maps_folder()), and --<kind>-format, the
// file kind (auto or one of `formats`), which needs it. Returns --<kind>.
CLI::Option* add_maps_options(CLI::App& app, const std::string& kind, std::string& folder,
                              const std::string& folder_help, std::string& format,
                              const std::vector<std::string>& formats) {
  auto* folder_option = app.add_option("--" + kind, folder, folder_help)->check(maps_folder(kind));
  std::vector<std::string> allowed{"auto"};
  allowed.insert(allowed.end(), formats.begin(), formats.end());
  app.add_option("--" + kind + "-format", format,
                 kind + " file kind: auto (first of exr, npy, png), " + join(formats, ", "))
      ->check(CLI::IsMember(allowed))
      ->needs(folder_option);
  return folder_option;
}

}  // namespace

void add_geometry_options(CLI::App& app, GeometryOptions& o) {
  auto* depth = add_maps_options(app, "depth", o.depth_dir,
                                 "folder of per-frame depth maps from a predictor (e.g. MapAnything): <image stem>.exr, "
                                 ".npy or .png; metric z-depth, 0 = unknown",
                                 o.depth_format, {"exr", "npy", "png16"});
  app.add_option("--depth-png-scale", o.depth_png_scale,
                 "metres per unit of 16-bit PNG depth (e.g. 0.001 for millimetres); required for PNG depth")
      ->check(CLI::PositiveNumber)
      ->needs(depth);
  app.add_flag("--depth-metric", o.depth_metric,
               "the depth maps are already in metres (MapAnything's metric depth): --scale applies to the poses "
               "only (default: to poses and depth alike)")
      ->needs(depth);
  auto* normals = add_maps_options(app, "normals", o.normals_dir,
                                   "folder of per-frame camera-space normal maps from a predictor (e.g. "
                                   "NormalCrafter): <image stem>.exr, .npy or .png (0.5 n + 0.5); 0 = unknown",
                                   o.normals_format, {"exr", "npy", "png"});
  app.add_option("--normals-convention", o.normals_convention,
                 "camera axes of the normal maps: opencv (x right, y down, z forward) or opengl (x right, y up, "
                 "z backward; converted by negating y and z)")
      ->check(CLI::IsMember({"opencv", "opengl"}))
      ->needs(normals);
}

std::string find_geometry_map(const std::string& dir, const std::string& image, const std::string& format) {
  const std::string stem = fs::path(image).stem().string();
  std::vector<std::string> exts;
  if (format == "auto") exts = {".exr", ".npy", ".png"};
  else if (format == "png16" || format == "png") exts = {".png"};
  else exts = {"." + format};
  std::error_code ec;
  for (const auto& ext : exts) {
    fs::path p = fs::path(dir) / (stem + ext);
    if (fs::is_regular_file(p, ec)) return p.string();
  }
  return "";
}

at::Tensor read_predicted_depth(const std::string& path, const GeometryOptions& o, int64_t h, int64_t w,
                                const std::string& image) {
  const std::string ext = lower_extension(path);
  at::Tensor d;
  if (ext == ".npy") {
    d = npy_map(path, false, h, w, image);
  } else if (ext == ".exr") {
    d = one_channel(read_image(path), path);
  } else if (ext == ".png") {
    const PngInfo info = png_info(path);
    if (info.bit_depth != 16)
      fail(path + ": " + std::to_string(info.bit_depth) +
           "-bit PNG: too few levels for depth; write a 16-bit greyscale PNG (with --depth-png-scale), EXR or NPY");
    if (info.color_type != 0) fail(path + ": PNG depth must be greyscale (1 channel)");
    if (!(o.depth_png_scale > 0))
      fail(path + ": 16-bit PNG depth needs --depth-png-scale (metres per unit, e.g. 0.001 for millimetres)");
    // read_image gives v / 65535: back to integer units, then to metres.
    d = (one_channel(read_image(path), path) * 65535.0).round() * o.depth_png_scale;
  } else {
    fail(path + ": unsupported depth file (exr, npy or 16-bit png)");
  }
  check_size(path, d.size(1), d.size(2), h, w, image);
  d = d.to(at::kFloat).contiguous();
  check_finite_map(d, path);
  auto negative = (d < 0).flatten();
  if (const int64_t n = negative.sum().item<int64_t>(); n > 0)
    fail(path + ": " + std::to_string(n) + " depth values are negative (min " + number(d.min().item<double>()) +
         ", first at " + pixel_str(negative.nonzero()[0][0].item<int64_t>(), w) + "); depth is >= 0, 0 = unknown");
  return d;
}

at::Tensor read_predicted_normals(const std::string& path, const GeometryOptions& o, int64_t h, int64_t w,
                                  const std::string& image) {
  const std::string ext = lower_extension(path);
  at::Tensor n;
  bool png = false;
  if (ext == ".npy") {
    n = npy_map(path, true, h, w, image);
  } else if (ext == ".exr" || ext == ".png") {
    png = ext == ".png";
    if (png) {
      const PngInfo info = png_info(path);
      if (info.bit_depth != 8 && info.bit_depth != 16)
        fail(path + ": PNG normals must be 8 or 16 bit, got " + std::to_string(info.bit_depth));
      if (info.color_type != 2 && info.color_type != 6) fail(path + ": PNG normals must be RGB (3 channels)");
    }
    n = read_image(path);
    if (n.size(0) == 4) n = n.narrow(0, 0, 3);  // alpha
    if (n.size(0) != 3)
      fail(path + ": normal map has " + std::to_string(n.size(0)) + " channels; expected 3 (x, y, z)");
  } else {
    fail(path + ": unsupported normals file (exr, npy or png)");
  }
  check_size(path, n.size(1), n.size(2), h, w, image);
  n = n.to(at::kFloat).contiguous();
  check_finite_map(n, path);
  if (png) {
    // 0.5 n + 0.5 per channel; a pixel whose channels are all 0 is unknown.
    auto unknown = (n == 0).all(0, true);
    n = at::where(unknown, at::zeros_like(n), 2 * n - 1);
  }
  const double tol = png ? kUnitTolerancePng : kUnitTolerance;
  auto len = n.to(at::kDouble).norm(2, 0);
  auto known = len > 0;
  auto off = (known & ((len - 1).abs() > tol)).flatten();
  if (const int64_t bad = off.sum().item<int64_t>(); bad > 0) {
    const int64_t first = off.nonzero()[0][0].item<int64_t>();
    fail(path + ": " + std::to_string(bad) + " of " + std::to_string(known.sum().item<int64_t>()) +
         " nonzero normals are not of unit length (within " + number(tol) + "; first at " + pixel_str(first, w) +
         ": |n| = " + number(len.flatten()[first].item<double>()) + ")" +
         (png ? "; PNG normals are read as 0.5 n + 0.5 per channel" : "") + "; expected unit vectors, 0 = unknown");
  }
  auto len_f = len.to(at::kFloat).unsqueeze(0);
  n = at::where(known.unsqueeze(0), n / len_f.clamp_min(1e-12f), at::zeros_like(n));
  if (o.normals_convention == "opengl") {  // (x right, y up, z backward) -> (x right, y down, z forward)
    n[1].neg_();
    n[2].neg_();
  }
  return n.contiguous();
}

FacingCount count_away_facing(const at::Tensor& normals, const at::Tensor& intrinsics) {
  check_shape(normals, {3, -1, -1}, "count_away_facing: normals", "(3,H,W)");
  const int64_t H = normals.size(1), W = normals.size(2);
  auto k = intrinsics.to(at::kDouble).flatten();
  const double fx = k[0].item<double>() * W, fy = k[1].item<double>() * H;
  const double cx = k[2].item<double>() * W, cy = k[3].item<double>() * H;
  auto opt = at::TensorOptions().dtype(at::kDouble);
  auto x = ((at::arange(W, opt) + 0.5 - cx) / fx).view({1, W});
  auto y = ((at::arange(H, opt) + 0.5 - cy) / fy).view({H, 1});
  auto n = normals.to(at::kDouble);
  auto dot = n[0] * x + n[1] * y + n[2];  // n . ((u+0.5-cx)/fx, (v+0.5-cy)/fy, 1)
  auto known = (n != 0).any(0);
  FacingCount c;
  c.known = known.sum().item<int64_t>();
  c.away = (known & (dot > 0)).sum().item<int64_t>();
  return c;
}

GeometryImport::GeometryImport(const GeometryOptions& o, double metric_scale, const std::vector<std::string>& images)
    : options_(o), metric_scale_(metric_scale), images_(images) {
  if (!o.any()) return;
  check_member(o.depth_format, {"auto", "exr", "npy", "png16"}, "depth format");
  check_member(o.normals_format, {"auto", "exr", "npy", "png"}, "normals format");
  check_member(o.normals_convention, {"opencv", "opengl"}, "normals convention");
  FLAT_CHECK(std::isfinite(o.depth_png_scale) && o.depth_png_scale >= 0, "--depth-png-scale must be >= 0");
  if (!o.depth_dir.empty() && o.depth_format == "png16" && !(o.depth_png_scale > 0))
    fail("--depth-format png16 needs --depth-png-scale (metres per unit, e.g. 0.001 for millimetres)");
  auto locate = [&](const std::string& dir, const std::string& format, const char* what, const char* flag,
                    std::vector<std::string>& files, std::vector<std::string>& kinds) -> std::string {
    std::error_code ec;
    if (!fs::is_directory(dir, ec)) fail(std::string(flag) + " " + dir + ": not a folder (" + what + " maps)");
    const std::string abs = fs::absolute(dir).lexically_normal().string();
    std::map<std::string, size_t> used;  // map file -> first frame
    for (size_t i = 0; i < images.size(); ++i) {
      std::string file = find_geometry_map(dir, images[i], format);
      const std::string stem = fs::path(images[i]).stem().string();
      if (file.empty())
        fail(std::string(flag) + " " + dir + ": no " + what + " map for frame " + std::to_string(i) + " (image " +
             images[i] + "): expected " +
             (format == "auto" ? stem + ".exr, " + stem + ".npy or " + stem + ".png"
                               : stem + (format == "png16" ? std::string(".png") : "." + format)) +
             " in " + abs + " (every frame needs one)");
      if (auto it = used.find(file); it != used.end())
        fail(std::string(flag) + " " + dir + ": frames " + std::to_string(it->second) + " and " + std::to_string(i) +
             " (images " + images[it->second] + " and " + images[i] + ") would share the " + what + " map " + file +
             " (maps are found by the image's file name)");
      used.emplace(file, i);
      std::string kind = lower_extension(file).substr(1);
      if (std::find(kinds.begin(), kinds.end(), kind) == kinds.end()) kinds.push_back(kind);
      files.push_back(std::move(file));
    }
    return abs;
  };
  if (!o.depth_dir.empty())
    depth_dir_abs_ = locate(o.depth_dir, o.depth_format, "depth", "--depth", depth_files_, depth_formats_);
  if (!o.normals_dir.empty())
    normals_dir_abs_ = locate(o.normals_dir, o.normals_format, "normals", "--normals", normals_files_, normals_formats_);
}

void GeometryImport::attach(Scene& scene, int64_t index, SceneFrame& frame, int64_t source_height,
                            int64_t source_width, const Distortion& distortion) {
  if (!active()) return;
  FLAT_CHECK(index >= 0 && size_t(index) < images_.size(), "GeometryImport::attach: frame index out of range");
  FLAT_CHECK(frame.intrinsics.defined() && frame.intrinsics.numel() == 4,
             "GeometryImport::attach: the frame's intrinsics must be set first");
  const std::string& image = images_[size_t(index)];
  const int64_t H = scene.height, W = scene.width;
  auto k = frame.intrinsics.to(at::kDouble);
  const double fx = k[0].item<double>() * W, fy = k[1].item<double>() * H;
  const double cx = k[2].item<double>() * W, cy = k[3].item<double>() * H;
  // As the importers treat the image: shrink to the scene size, then undistort at that size.
  auto follow_image = [&](const at::Tensor& map, bool normals) {
    auto m = normals ? resize_normals(map.unsqueeze(0), H, W)[0] : resize_depth(map.unsqueeze(0), H, W)[0];
    if (distortion.any()) m = undistort_nearest(m, fx, fy, cx, cy, distortion);
    return m.contiguous();
  };
  const std::string ext = float_map_extension();
  if (!depth_files_.empty()) {
    const std::string& file = depth_files_[size_t(index)];
    const double depth_scale = options_.depth_metric ? 1.0 : metric_scale_;
    auto d = follow_image(read_predicted_depth(file, options_, source_height, source_width, image) * depth_scale,
                          false);
    frame.depth = "depth/" + frame_stem(index) + ext;
    fs::create_directories(scene.path("depth"));
    write_depth(scene.path(frame.depth), d);
  }
  if (!normals_files_.empty()) {
    const std::string& file = normals_files_[size_t(index)];
    auto n = follow_image(read_predicted_normals(file, options_, source_height, source_width, image), true);
    const FacingCount c = count_away_facing(n, frame.intrinsics);
    if (c.known > 0 && 2 * c.away > c.known) {
      const bool gl = options_.normals_convention == "opengl";
      fail(file + ": " + std::to_string(c.away) + " of " + std::to_string(c.known) +
           " known normals face away from the camera (n . view ray > 0) when read in " + (gl ? "OpenGL" : "OpenCV") +
           " axes: the maps are probably in the other convention; try --normals-convention " +
           (gl ? "opencv (x right, y down, z forward)" : "opengl (x right, y up, z backward)"));
    }
    known_ += c.known;
    away_ += c.away;
    if (c.away > 0) {
      ++frames_with_away_;
      spdlog::debug("{}: {} of {} known normals face away from the camera (kept)", file, c.away, c.known);
    }
    frame.normals = "normals/" + frame_stem(index) + ext;
    fs::create_directories(scene.path("normals"));
    write_normals(scene.path(frame.normals), n);
  }
}

void GeometryImport::finish(Scene& scene) const {
  if (!depth_files_.empty()) {
    scene.has_depth = true;
    scene.depth_source = join(depth_formats_, "+") + " files from " + depth_dir_abs_;
    if (std::find(depth_formats_.begin(), depth_formats_.end(), "png") != depth_formats_.end())
      scene.depth_source += ", " + number(options_.depth_png_scale) + " m per PNG unit";
    scene.depth_source += options_.depth_metric ? " (metric as given; the poses' scale " + number(metric_scale_) + ")"
                                                : " (metric scale " + number(metric_scale_) + ")";
    spdlog::info("{}: depth of {} frames: {}", scene.name, depth_files_.size(), scene.depth_source);
  }
  if (!normals_files_.empty()) {
    scene.has_normals = true;
    scene.normals_source = join(normals_formats_, "+") + " files from " + normals_dir_abs_ + ", " +
                           (options_.normals_convention == "opengl" ? "opengl -> opencv" : "opencv");
    spdlog::info("{}: normals of {} frames: {}", scene.name, normals_files_.size(), scene.normals_source);
    if (away_ > 0)
      spdlog::info("{}: {} of {} known normals ({:.2f}%, in {} frames) face away from their camera; kept as they are",
                   scene.name, away_, known_, 100.0 * double(away_) / double(std::max<int64_t>(known_, 1)),
                   frames_with_away_);
  }
}

}  // namespace flat::data
