// Synthetic rooms in RealEstate10K's and DL3DV's (nerfstudio) formats, with
// manifest.json and the metric ground truth (include/flat/data/synthetic_export.h).
#include "flat/data/synthetic_export.h"

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <sstream>

#include <nlohmann/json.hpp>
#include <spdlog/spdlog.h>

#include "flat/core/atomic_file.h"
#include "flat/core/error.h"
#include "flat/core/image_io.h"
#include "flat/core/npy.h"
#include "flat/core/staged_dir.h"
#include "data/synthetic/shapes.h"

namespace flat::data {

namespace fs = std::filesystem;
using nlohmann::json;

namespace {

constexpr double kFrameMicros = 1001000000.0 / 30000.0;  // 29.97 fps: 33366.67 us, as YouTube videos
constexpr int64_t kDl3dvDeclaredScale = 4;               // transforms.json declares 4x the images_4 size

uint64_t splitmix64(uint64_t x) {
  x += 0x9E3779B97F4A7C15ull;
  x = (x ^ (x >> 30)) * 0xBF58476D1CE4E5B9ull;
  x = (x ^ (x >> 27)) * 0x94D049BB133111EBull;
  return x ^ (x >> 31);
}

// A name like the real datasets' (RE10K: 16 hex digits; DL3DV: 64), fixed by (seed, index, format).
std::string hex_name(uint64_t seed, int64_t index, const std::string& format, int digits) {
  uint64_t h = splitmix64(seed ^ splitmix64(uint64_t(index) ^ (format == "re10k" ? 0x5245ull : 0x444Cull)));
  std::string out;
  while (int(out.size()) < digits) {
    h = splitmix64(h);
    char part[17];
    std::snprintf(part, sizeof(part), "%016llx", static_cast<unsigned long long>(h));
    out += part;
  }
  return out.substr(0, size_t(digits));
}

std::string number(double v) {
  char text[40];
  std::snprintf(text, sizeof(text), "%.10g", v);
  return text;
}

// NPY files through flat::write_npy (include/flat/core/npy.h: version 1.0, '<f4', C order).
void write_npy_float32(const std::string& path, const at::Tensor& t) {
  write_npy(path, t.detach().to(at::kCPU, at::kFloat).contiguous());
}

// OpenCV camera axes (x right, y down, z forward) -> OpenGL (x right, y up, z backward), (3,H,W).
at::Tensor opengl_normals(const at::Tensor& n_cv) {
  return n_cv * at::tensor({1.0f, -1.0f, -1.0f}).view({3, 1, 1});
}

// The row-major 3x4 world-to-camera of a (4,4) OpenCV c2w, translation in units.
std::array<double, 12> world_to_camera_units(const at::Tensor& c2w, double unit) {
  auto m = c2w.to(at::kDouble).contiguous();
  auto R = m.narrow(0, 0, 3).narrow(1, 0, 3), t = m.narrow(0, 0, 3).select(1, 3);
  auto Rt = R.t().contiguous();
  auto tw = (-at::matmul(Rt, t) / unit).contiguous();
  std::array<double, 12> out{};
  for (int r = 0; r < 3; ++r) {
    for (int c = 0; c < 3; ++c) out[size_t(4 * r + c)] = Rt[r][c].item<double>();
    out[size_t(4 * r + 3)] = tw[r].item<double>();
  }
  return out;
}

// Which clips are corrupt and how: K distinct indices by seed, kinds alternating from a seeded start.
std::vector<std::string> corrupt_kinds(const SynthExportOptions& o) {
  std::vector<std::string> kinds(size_t(o.count));
  if (o.corrupt == 0) return kinds;
  synth::Random rng(splitmix64(o.seed ^ 0xC022ull) ^ (o.format == "re10k" ? 1u : 2u));
  std::vector<int64_t> order(size_t(o.count));
  for (int64_t i = 0; i < o.count; ++i) order[size_t(i)] = i;
  for (int64_t j = 0; j < o.corrupt; ++j) std::swap(order[size_t(j)], order[size_t(rng.integer(j, o.count - 1))]);
  const char* re10k[2] = {"truncated_line", "missing_frame"};
  const char* dl3dv[2] = {"truncated_json", "non_orthonormal"};
  const int64_t start = rng.integer(0, 1);
  for (int64_t j = 0; j < o.corrupt; ++j)
    kinds[size_t(order[size_t(j)])] = (o.format == "re10k" ? re10k : dl3dv)[(start + j) % 2];
  return kinds;
}

json conventions(const SynthExportOptions& o) {
  json c;
  c["units"] = "translations and depth are in units of `unit` metres: metres = value * unit (import with --scale unit)";
  c["truth"] = std::string(o.format == "re10k" ? "truth/<clip>/" : "<scene>/truth/") +
               ": flat scene folder (docs/scene_format.md): OpenCV camera-to-world in metres, "
               "normalised intrinsics, metric z-depth and OpenCV camera-space normals, the exact values exported";
  if (o.format == "re10k") {
    c["cameras"] = "cameras/<clip>.txt: line 1 the URL; then per frame 'timestamp fx fy cx cy 0 0' (intrinsics "
                   "divided by width, height) and a row-major 3x4 world-to-camera matrix, OpenCV axes, translation in units";
    c["frames"] = "frames/<clip>/<timestamp>.png: 8-bit RGB";
    c["depth"] = "depth/<clip>/<timestamp>.npy: float32 (H,W) z-depth in units, 0 = unknown";
    c["normals"] = "normals/<clip>/<timestamp>.png: 8-bit RGB = round(255 * (0.5 n + 0.5)), n the OpenGL camera-space "
                   "normal (x right, y up, z backward = OpenCV with y, z negated); bytes (0,0,0) = unknown";
  } else {
    c["cameras"] = "<scene>/transforms.json: nerfstudio; fl_x fl_y cx cy in pixels of w x h = 4x the images_4 size; "
                   "camera_model OPENCV, zero distortion; frames[].transform_matrix camera-to-world 4x4, OpenGL axes "
                   "(x right, y up, z backward), translation in units";
    c["frames"] = "<scene>/images_4/frame_%05d.png (from 1): 8-bit RGB";
    c["depth"] = "<scene>/depth/frame_%05d.png: 16-bit, round(depth_m * 1000 / unit) (millimetres of the pose unit), "
                 "0 = unknown (also frames[].depth_file_path)";
    c["normals"] = "<scene>/normals/frame_%05d.npy: float32 (H,W,3) OpenGL camera-space unit normals, 0 = unknown";
  }
  return c;
}

// ---- RealEstate10K --------------------------------------------------------

json write_re10k_clip(const SynthScene& s, const std::string& root, const std::string& name, uint64_t clip_seed,
                      const std::string& corrupt, double unit) {
  const int64_t F = s.images.size(0);
  synth::Random rng(splitmix64(clip_seed ^ 0x7265313070ull));
  // Timestamps as YouTube's 29.97 fps give them: 33366/33367 us apart, from a start in the video.
  const int64_t start = int64_t(std::llround(double(rng.integer(30, 18000)) * kFrameMicros));
  std::vector<std::string> stamps;
  for (int64_t f = 0; f < F; ++f) stamps.push_back(std::to_string(start + std::llround(double(f) * kFrameMicros)));
  static const char* b64 = "ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789-_";
  std::string video;
  for (int k = 0; k < 11; ++k) video += b64[rng.integer(0, 63)];

  std::vector<std::string> lines{"https://www.youtube.com/watch?v=" + video};
  for (int64_t f = 0; f < F; ++f) {
    auto k = s.cameras.intrinsics[f].to(at::kDouble);
    std::string line = stamps[size_t(f)];
    for (int c = 0; c < 4; ++c) line += " " + number(k[c].item<double>());
    line += " 0 0";
    for (double v : world_to_camera_units(s.cameras.c2w[f], unit)) line += " " + number(v);
    lines.push_back(line);
  }
  json c = nullptr;
  int64_t missing = -1;
  if (corrupt == "truncated_line") {
    // A line cut in the middle of a number (an interrupted download or write): fewer than 18 numbers remain.
    const int64_t f = rng.integer(0, F - 1);
    std::string& line = lines[size_t(f + 1)];
    std::vector<size_t> starts;
    for (size_t i = 0; i < line.size(); ++i)
      if (line[i] != ' ' && (i == 0 || line[i - 1] == ' ')) starts.push_back(i);
    const size_t k = size_t(rng.integer(2, 12));  // tokens kept whole: the timestamp and k-1 numbers
    const size_t end = starts[k] + std::max<size_t>(1, (line.find(' ', starts[k]) - starts[k]) / 2);
    line = line.substr(0, end);
    c = {{"kind", corrupt},
         {"frame", f},
         {"timestamp", stamps[size_t(f)]},
         {"line", f + 2},
         {"numbers_left", int64_t(k)},
         {"file_ends_here", f == F - 1},
         {"what", "line " + std::to_string(f + 2) + " of cameras/" + name + ".txt is cut after " +
                      std::to_string(line.size()) + " characters (" + std::to_string(k) +
                      " of 18 numbers, then part of one)"},
         {"expect", "the importer refuses the camera file, naming the line"}};
  } else if (corrupt == "missing_frame") {
    missing = rng.integer(0, F - 1);
    c = {{"kind", corrupt},
         {"frame", missing},
         {"timestamp", stamps[size_t(missing)]},
         {"what", "frames/" + name + "/" + stamps[size_t(missing)] + ".png is missing (its depth and normals are there)"},
         {"expect", "the importer refuses the clip: " + std::to_string(F - 1) + " images for " + std::to_string(F) +
                        " camera lines"}};
  }
  std::string text;
  for (size_t i = 0; i < lines.size(); ++i) {
    text += lines[i];
    const bool cut_last = corrupt == "truncated_line" && i + 1 == lines.size();
    if (!cut_last) text += "\n";
  }
  write_file_atomic((fs::path(root) / "cameras" / (name + ".txt")).string(), text);

  const fs::path frames = fs::path(root) / "frames" / name, depth = fs::path(root) / "depth" / name,
                 normals = fs::path(root) / "normals" / name;
  for (const auto& d : {frames, depth, normals}) fs::create_directories(d);
  for (int64_t f = 0; f < F; ++f) {
    const std::string& ts = stamps[size_t(f)];
    if (f != missing) write_image((frames / (ts + ".png")).string(), s.images[f]);
    write_npy_float32((depth / (ts + ".npy")).string(), s.depth[f][0] / unit);
    auto valid = (s.depth[f] > 0).to(at::kFloat);
    write_image((normals / (ts + ".png")).string(), (opengl_normals(s.normals[f]) * 0.5f + 0.5f) * valid);
  }
  json clip;
  clip["camera_file"] = "cameras/" + name + ".txt";
  clip["frames_dir"] = "frames/" + name;
  clip["depth_dir"] = "depth/" + name;
  clip["normals_dir"] = "normals/" + name;
  clip["url"] = lines[0];
  clip["timestamps"] = stamps;
  clip["corrupt"] = c;
  return clip;
}

// ---- DL3DV (nerfstudio transforms.json) ------------------------------------

json write_dl3dv_scene(const SynthScene& s, const std::string& root, const std::string& name, uint64_t clip_seed,
                       const std::string& corrupt, double unit) {
  const int64_t F = s.images.size(0), H = s.images.size(2), W = s.images.size(3);
  const int64_t DW = W * kDl3dvDeclaredScale, DH = H * kDl3dvDeclaredScale;
  synth::Random rng(splitmix64(clip_seed ^ 0x646c3364ull));
  const fs::path dir = fs::path(root) / name;
  for (const char* sub : {"images_4", "depth", "normals"}) fs::create_directories(dir / sub);
  // Every frame of a synthetic scene has the same intrinsics.
  auto k = s.cameras.intrinsics[0].to(at::kDouble);
  json doc;
  doc["w"] = DW;
  doc["h"] = DH;
  doc["fl_x"] = k[0].item<double>() * double(DW);
  doc["fl_y"] = k[1].item<double>() * double(DH);
  doc["cx"] = k[2].item<double>() * double(DW);
  doc["cy"] = k[3].item<double>() * double(DH);
  doc["k1"] = 0.0;
  doc["k2"] = 0.0;
  doc["p1"] = 0.0;
  doc["p2"] = 0.0;
  doc["camera_model"] = "OPENCV";
  doc["frames"] = json::array();
  const double max_depth_units = s.depth.max().item<double>() * 1000.0 / unit;
  if (max_depth_units > 65535.0)
    fail("dl3dv export: " + name + ": depth up to " + number(s.depth.max().item<double>()) + " m is " +
         number(max_depth_units) + " > 65535 in 16-bit millimetres of the unit " + number(unit) +
         " m; pass a larger --unit");
  for (int64_t f = 0; f < F; ++f) {
    char stem[32];
    std::snprintf(stem, sizeof(stem), "frame_%05lld", static_cast<long long>(f + 1));
    auto c2w = s.cameras.c2w[f].to(at::kDouble).clone();
    c2w.select(1, 1).neg_();  // OpenCV -> OpenGL camera axes: negate the y and z columns
    c2w.select(1, 2).neg_();
    c2w.select(1, 3).narrow(0, 0, 3).div_(unit);
    json m = json::array();
    for (int r = 0; r < 4; ++r) {
      json row = json::array();
      for (int c = 0; c < 4; ++c) row.push_back(c2w[r][c].item<double>());
      m.push_back(row);
    }
    doc["frames"].push_back({{"file_path", std::string("images_4/") + stem + ".png"},
                             {"depth_file_path", std::string("depth/") + stem + ".png"},
                             {"transform_matrix", m},
                             {"colmap_im_id", f + 1}});
    write_image((dir / "images_4" / (std::string(stem) + ".png")).string(), s.images[f]);
    auto mm = at::round(s.depth[f].to(at::kDouble) * (1000.0 / unit));
    write_image((dir / "depth" / (std::string(stem) + ".png")).string(), (mm / 65535.0).to(at::kFloat), true);
    write_npy_float32((dir / "normals" / (std::string(stem) + ".npy")).string(),
                      opengl_normals(s.normals[f]).permute({1, 2, 0}));
  }
  json c = nullptr;
  if (corrupt == "non_orthonormal") {
    // A rotation that is no rotation (column 2 a copy of column 0, rank 2): a broken pose writer.
    const int64_t f = rng.integer(0, F - 1);
    auto& m = doc["frames"][size_t(f)]["transform_matrix"];
    for (int r = 0; r < 3; ++r) m[size_t(r)][2] = m[size_t(r)][0];
    c = {{"kind", corrupt},
         {"frame", f},
         {"file_path", doc["frames"][size_t(f)]["file_path"]},
         {"what", "frames[" + std::to_string(f) + "].transform_matrix: rotation column 2 replaced by column 0 (rank 2)"},
         {"expect", "the importer refuses the scene, naming the frame (a degenerate rotation is not re-orthonormalised)"}};
  }
  std::string text = doc.dump(4) + "\n";
  if (corrupt == "truncated_json") {
    // Cut in the middle (an interrupted download): never valid JSON, the outer object is open.
    const size_t full = text.size();
    const size_t keep = size_t(rng.integer(int64_t(full * 3 / 10), int64_t(full * 7 / 10)));
    text = text.substr(0, keep);
    c = {{"kind", corrupt},
         {"bytes_kept", int64_t(keep)},
         {"bytes_full", int64_t(full)},
         {"what", name + "/transforms.json is cut after " + std::to_string(keep) + " of " + std::to_string(full) + " bytes"},
         {"expect", "the importer refuses it as invalid JSON"}};
  }
  write_file_atomic((dir / "transforms.json").string(), text);
  json clip;
  clip["transforms"] = name + "/transforms.json";
  clip["declared_size"] = {DH, DW};
  clip["corrupt"] = c;
  return clip;
}

}  // namespace

uint64_t synth_scene_seed(uint64_t seed, int64_t index) { return seed * 1000003ull + uint64_t(index); }

void SynthExportOptions::check() const {
  if (format != "re10k" && format != "dl3dv") fail("synthetic export: format must be re10k or dl3dv, got '" + format + "'");
  FLAT_CHECK(count >= 1, "synthetic export: count must be >= 1, got " + std::to_string(count));
  FLAT_CHECK(corrupt >= 0 && corrupt <= count, "synthetic export: corrupt must be in [0, count = " +
                                                   std::to_string(count) + "], got " + std::to_string(corrupt));
  FLAT_CHECK(std::isfinite(unit) && unit > 0, "synthetic export: unit must be a positive number of metres, got " + number(unit));
  synth.check();
}

std::vector<ExportedClip> export_synthetic(const SynthExportOptions& o, const std::string& root) {
  o.check();
  if (!image_io_available())
    fail("synthetic export: needs PNG writing (OpenImageIO or libpng), which this build lacks: the formats are PNG files");
  StagedDir staged(root, o.overwrite);
  const std::vector<std::string> kinds = corrupt_kinds(o);
  json manifest;
  manifest["format"] = "flat-synth-export";
  manifest["version"] = 1;
  manifest["export_format"] = o.format;
  manifest["seed"] = o.seed;
  manifest["unit"] = o.unit;
  manifest["count"] = o.count;
  manifest["frames"] = o.synth.frames;
  manifest["height"] = o.synth.height;
  manifest["width"] = o.synth.width;
  manifest["family"] = o.synth.family;
  manifest["motion"] = o.synth.motion;
  manifest["truth_folders"] = o.truth;  // clips[].truth names each
  manifest["conventions"] = conventions(o);
  // Command lines of the rehearsal (flat_import; --depth/--normals attach the predictor-style maps).
  const std::string scale = " --scale " + number(o.unit);
  if (o.format == "re10k")
    manifest["import"] = {
        {"clip", "flat_import re10k --in ROOT/cameras/<clip>.txt --frames-dir ROOT/frames/<clip> --out OUT/<clip>" +
                     scale + " --depth ROOT/depth/<clip> --normals ROOT/normals/<clip> --normals-convention opengl"},
        {"batch", "flat_import re10k --in ROOT/cameras --frames-dir ROOT/frames --out OUT" + scale +
                      " --depth ROOT/depth --normals ROOT/normals --normals-convention opengl"}};
  else
    manifest["import"] = {
        {"clip", "flat_import transforms --in ROOT/<scene> --out OUT/<scene>" + scale +
                     " --depth ROOT/<scene>/depth --depth-png-scale 0.001 --normals ROOT/<scene>/normals"
                     " --normals-convention opengl"},
        {"batch", "flat_import transforms --in ROOT --out OUT" + scale +
                      " --depth 'ROOT/{clip}/depth' --depth-png-scale 0.001 --normals 'ROOT/{clip}/normals'"
                      " --normals-convention opengl"}};
  manifest["clips"] = json::array();
  manifest["corrupt"] = json::array();
  std::vector<ExportedClip> out;
  for (int64_t i = 0; i < o.count; ++i) {
    ExportedClip e;
    e.index = i;
    e.synth_seed = synth_scene_seed(o.seed, i);
    e.name = hex_name(o.seed, i, o.format, o.format == "re10k" ? 16 : 64);
    e.corrupt = kinds[size_t(i)];
    SynthOptions s = o.synth;
    s.seed = e.synth_seed;
    SynthScene scene = render_synthetic_scene(s);
    e.motion = scene.motion;
    json clip = o.format == "re10k" ? write_re10k_clip(scene, staged.path(), e.name, e.synth_seed, e.corrupt, o.unit)
                                    : write_dl3dv_scene(scene, staged.path(), e.name, e.synth_seed, e.corrupt, o.unit);
    clip["name"] = e.name;
    clip["index"] = i;
    clip["synth_seed"] = e.synth_seed;
    clip["motion"] = e.motion;
    clip["frames"] = scene.images.size(0);
    clip["depth_max_m"] = scene.depth.max().item<double>();
    if (o.truth) {
      // dl3dv: inside the scene folder, so that a batch import of ROOT (one scene per
      // folder holding transforms.json) sees no folder without one.
      const std::string truth = o.format == "re10k" ? "truth/" + e.name : e.name + "/truth";
      write_synthetic_scene(scene, staged.file(truth), e.name,
                            "flat_synth export " + o.format + " family=" + o.synth.family + " motion=" + e.motion +
                                " seed=" + std::to_string(e.synth_seed));
      clip["truth"] = truth;
    }
    if (!e.corrupt.empty()) manifest["corrupt"].push_back(e.name);
    manifest["clips"].push_back(clip);
    spdlog::info("{} {} {}: {} frames, motion {}{}", o.format, i, e.name, scene.images.size(0), e.motion,
                 e.corrupt.empty() ? "" : " (corrupt: " + e.corrupt + ")");
    out.push_back(std::move(e));
  }
  write_file_atomic(staged.file("manifest.json"), manifest.dump(1) + "\n");
  staged.commit();
  return out;
}

}  // namespace flat::data
