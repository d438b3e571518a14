#include "flat/data/scene.h"

#include <algorithm>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <tuple>

#include <nlohmann/json.hpp>

#include "flat/camera/camera_json.h"
#include "flat/core/atomic_file.h"
#include "flat/core/error.h"

namespace flat::data {

using nlohmann::json;
namespace fs = std::filesystem;

std::string latent_set_key(int64_t height, int64_t width, int64_t frames) {
  return std::to_string(height) + "x" + std::to_string(width) + "_f" + std::to_string(frames);
}

std::string latent_set_key(const LatentInfo& set) { return latent_set_key(set.height, set.width, set.frames()); }

const LatentInfo* find_latent_set(const Scene& scene, int64_t height, int64_t width, int64_t frames) {
  for (const auto& set : scene.latent_sets)
    if (set.height == height && set.width == width && set.frames() == frames) return &set;
  return nullptr;
}

std::string latent_set_list(const Scene& scene) {
  std::string out;
  for (const auto& set : scene.latent_sets) out += (out.empty() ? "" : ", ") + latent_set_key(set);
  return out.empty() ? "none" : out;
}

void select_latent_set(Scene& scene, int64_t height, int64_t width, int64_t frames) {
  const LatentInfo* set = find_latent_set(scene, height, width, frames);
  if (!set)
    fail(scene.json_path() + ": scene '" + scene.name + "' has no latent set " + latent_set_key(height, width, frames) +
         " (" + std::to_string(frames) + "-frame windows at " + std::to_string(height) + "x" + std::to_string(width) +
         "); it holds: " + latent_set_list(scene) + " (flat_latents --size " + std::to_string(height) + "x" +
         std::to_string(width) + " --window " + std::to_string(frames) + " makes it)");
  scene.latents = *set;
}

void parse_latent_set_key(const std::string& key, int64_t& height, int64_t& width, int64_t& frames,
                          const std::string& what) {
  long long h = 0, w = 0, f = 0;
  char tail = 0;
  if (std::sscanf(key.c_str(), "%lldx%lld_f%lld%c", &h, &w, &f, &tail) != 3 || h <= 0 || w <= 0 || f <= 0)
    fail(what + ": a latent set is named HEIGHTxWIDTH_fFRAMES (e.g. 176x320_f17), got '" + key + "'");
  height = h;
  width = w;
  frames = f;
}

void choose_latent_set(Scene& scene, const std::string& key) {
  if (!key.empty()) {
    int64_t h = 0, w = 0, f = 0;
    parse_latent_set_key(key, h, w, f, "--latent-set");
    select_latent_set(scene, h, w, f);
    return;
  }
  if (scene.latent_sets.size() > 1 && !scene.latents.present())
    fail(scene.json_path() + ": scene '" + scene.name + "' holds several latent sets (" + latent_set_list(scene) +
         "): choose one with --latent-set");
}

void put_latent_set(Scene& scene, const LatentInfo& set) {
  const std::string key = latent_set_key(set);
  auto& sets = scene.latent_sets;
  sets.erase(std::remove_if(sets.begin(), sets.end(), [&](const LatentInfo& s) { return latent_set_key(s) == key; }),
             sets.end());
  sets.push_back(set);
  std::sort(sets.begin(), sets.end(), [](const LatentInfo& a, const LatentInfo& b) {
    return std::make_tuple(a.height, a.width, a.frames()) < std::make_tuple(b.height, b.width, b.frames());
  });
}

std::string frame_stem(int64_t index) {
  char buf[32];
  std::snprintf(buf, sizeof(buf), "%06lld", static_cast<long long>(index));
  return buf;
}

camera::Cameras Scene::cameras() const {
  std::vector<int64_t> all(frames.size());
  for (size_t i = 0; i < all.size(); ++i) all[i] = int64_t(i);
  return cameras(all);
}

camera::Cameras Scene::cameras(const std::vector<int64_t>& indices) const {
  FLAT_CHECK(!indices.empty(), json_path() + ": no frames selected");
  std::vector<at::Tensor> ks, ms;
  for (int64_t i : indices) {
    FLAT_CHECK(i >= 0 && i < size(), json_path() + ": frame index " + std::to_string(i) + " out of range [0, " +
                                         std::to_string(size()) + ")");
    ks.push_back(frames[size_t(i)].intrinsics);
    ms.push_back(frames[size_t(i)].c2w);
  }
  return {at::stack(ks), at::stack(ms)};
}

namespace {

std::string optional_string(const json& e, const char* key, const std::string& where) {
  if (!e.contains(key) || e[key].is_null()) return "";
  if (!e[key].is_string()) fail(where + ": '" + key + "' must be a string (a path relative to the scene folder)");
  return e[key].get<std::string>();
}

int64_t integer(const json& e, const char* key, const std::string& where) {
  if (!e.contains(key)) fail(where + ": missing key '" + key + "'");
  if (!e[key].is_number_integer()) fail(where + ": '" + key + "' must be an integer, got " + e[key].dump());
  return e[key].get<int64_t>();
}

LatentInfo parse_latents(const json& l, const std::string& where) {
  if (!l.is_object()) fail(where + ": must be an object");
  LatentInfo info;
  info.file = optional_string(l, "file", where);
  if (info.file.empty()) fail(where + ": missing 'file'");
  info.encoder = optional_string(l, "encoder", where);
  if (info.encoder != "pretrained" && info.encoder != "random")
    fail(where + ": 'encoder' must be \"pretrained\" or \"random\", got \"" + info.encoder + "\"");
  info.weights = optional_string(l, "weights", where);
  info.weights_digest = optional_string(l, "weights_digest", where);
  if (l.contains("seed")) info.seed = integer(l, "seed", where);
  info.height = integer(l, "height", where);
  info.width = integer(l, "width", where);
  if (l.contains("dtype")) info.dtype = optional_string(l, "dtype", where);
  if (l.contains("camera_plucker")) {
    if (!l["camera_plucker"].is_boolean()) fail(where + ": 'camera_plucker' must be true or false");
    info.plucker = l["camera_plucker"].get<bool>();
  }
  if (!l.contains("windows") || !l["windows"].is_array() || l["windows"].empty())
    fail(where + ": 'windows' must be a non-empty array of {start, count}");
  for (size_t i = 0; i < l["windows"].size(); ++i) {
    std::string w = where + ".windows[" + std::to_string(i) + "]";
    info.windows.push_back({integer(l["windows"][i], "start", w), integer(l["windows"][i], "count", w)});
  }
  return info;
}

json latents_json(const LatentInfo& info) {
  json l;
  l["file"] = info.file;
  l["encoder"] = info.encoder;
  l["weights"] = info.weights;
  if (!info.weights_digest.empty()) l["weights_digest"] = info.weights_digest;
  l["seed"] = info.seed;
  l["height"] = info.height;
  l["width"] = info.width;
  l["dtype"] = info.dtype;
  if (info.plucker) l["camera_plucker"] = true;
  l["windows"] = json::array();
  for (const auto& w : info.windows) l["windows"].push_back({{"start", w.start}, {"count", w.count}});
  return l;
}

}  // namespace

Scene read_scene(const std::string& dir, bool check_files) {
  Scene scene;
  scene.dir = dir;
  while (scene.dir.size() > 1 && scene.dir.back() == '/') scene.dir.pop_back();
  const std::string file = scene.json_path();
  std::ifstream in(file);
  if (!in) fail(file + ": cannot open scene file (is '" + dir + "' a scene folder?)");
  json doc;
  try {
    doc = json::parse(in);
  } catch (const json::exception& e) {
    fail(file + ": invalid JSON: " + e.what());
  }
  if (!doc.is_object()) fail(file + ": top level must be an object");
  if (!doc.contains("format") || doc["format"] != "flat-scene")
    fail(file + ": 'format' must be \"flat-scene\"");
  if (!doc.contains("version") || !doc["version"].is_number_integer())
    fail(file + ": missing integer 'version'");
  const int version = doc["version"].get<int>();
  if (version != 1 && version != kSceneFormatVersion)
    fail(file + ": unsupported scene format version " + doc["version"].dump() + " (this build reads versions 1 to " +
         std::to_string(kSceneFormatVersion) + ")");
  scene.name = optional_string(doc, "name", file);
  if (scene.name.empty()) scene.name = fs::path(scene.dir).filename().string();
  scene.source = optional_string(doc, "source", file);
  if (doc.contains("metric_scale")) {
    if (!doc["metric_scale"].is_number() || !(doc["metric_scale"].get<double>() > 0))
      fail(file + ": 'metric_scale' must be a positive number");
    scene.metric_scale = doc["metric_scale"].get<double>();
  }
  scene.width = integer(doc, "width", file);
  scene.height = integer(doc, "height", file);
  scene.packed = optional_string(doc, "packed", file);
  scene.depth_source = optional_string(doc, "depth_source", file);
  scene.normals_source = optional_string(doc, "normals_source", file);
  if (!doc.contains("frames") || !doc["frames"].is_array() || doc["frames"].empty())
    fail(file + ": 'frames' must be a non-empty array");
  const auto& frames = doc["frames"];
  for (size_t i = 0; i < frames.size(); ++i) {
    const std::string where = file + ": frames[" + std::to_string(i) + "]";
    SceneFrame f;
    int64_t w = 0, h = 0;
    camera::parse_camera_entry(frames[i], where, f.intrinsics, f.c2w, w, h);
    if (w != scene.width || h != scene.height)
      fail(where + ": size " + std::to_string(w) + "x" + std::to_string(h) + " differs from the scene's " +
           std::to_string(scene.width) + "x" + std::to_string(scene.height));
    f.image = optional_string(frames[i], "image", where);
    f.depth = optional_string(frames[i], "depth", where);
    f.normals = optional_string(frames[i], "normals", where);
    if (frames[i].contains("timestamp")) {
      if (!frames[i]["timestamp"].is_number()) fail(where + ": 'timestamp' must be a number");
      f.timestamp = frames[i]["timestamp"].get<double>();
    }
    scene.frames.push_back(std::move(f));
  }
  scene.has_depth = !scene.frames[0].depth.empty();
  scene.has_normals = !scene.frames[0].normals.empty();
  for (const char* key : {"packed_depth", "packed_normals"})
    if (doc.contains(key) && !doc[key].is_boolean()) fail(file + ": '" + key + "' must be true or false");
  if (doc.value("packed_depth", false)) scene.has_depth = true;
  if (doc.value("packed_normals", false)) scene.has_normals = true;
  // Version 1: one set under "latents"; version 2: a list under "latent_sets".
  if (version == 1 && doc.contains("latents") && !doc["latents"].is_null())
    scene.latent_sets.push_back(parse_latents(doc["latents"], file + ": latents"));
  if (version >= 2 && doc.contains("latent_sets")) {
    if (!doc["latent_sets"].is_array()) fail(file + ": 'latent_sets' must be an array");
    for (size_t i = 0; i < doc["latent_sets"].size(); ++i) {
      const std::string where = file + ": latent_sets[" + std::to_string(i) + "]";
      LatentInfo set = parse_latents(doc["latent_sets"][i], where);
      if (find_latent_set(scene, set.height, set.width, set.frames()))
        fail(where + ": a second set " + latent_set_key(set) + " (one set per size and window)");
      put_latent_set(scene, set);
    }
  }
  if (scene.latent_sets.size() == 1) scene.latents = scene.latent_sets[0];
  validate_scene(scene, check_files);
  return scene;
}

void validate_scene(const Scene& scene, bool check_files) {
  const std::string file = scene.json_path();
  FLAT_CHECK(scene.width > 0 && scene.height > 0, file + ": 'width' and 'height' must be positive");
  FLAT_CHECK(!scene.frames.empty(), file + ": no frames");
  const bool packed = !scene.packed.empty();
  auto exists = [&](const std::string& rel, const std::string& where) {
    if (check_files && !fs::exists(scene.path(rel))) fail(where + ": file '" + scene.path(rel) + "' does not exist");
  };
  if (packed) exists(scene.packed, file + ": packed");
  for (size_t i = 0; i < scene.frames.size(); ++i) {
    const auto& f = scene.frames[i];
    const std::string where = file + ": frames[" + std::to_string(i) + "]";
    FLAT_CHECK(f.intrinsics.defined() && f.intrinsics.numel() == 4, where + ": intrinsics must hold 4 numbers");
    FLAT_CHECK(f.c2w.defined() && f.c2w.numel() == 16, where + ": c2w must be 4x4");
    if (f.image.empty() && !packed) fail(where + ": missing 'image' (and the scene is not packed)");
    // Depth and normals are all-or-none so a batch never mixes supervised and unsupervised frames.
    if (!packed && (f.depth.empty() == scene.has_depth))
      fail(where + ": 'depth' must be given for every frame or for none (frames[0] " +
           (scene.has_depth ? "has" : "has no") + " depth)");
    if (!packed && (f.normals.empty() == scene.has_normals))
      fail(where + ": 'normals' must be given for every frame or for none (frames[0] " +
           (scene.has_normals ? "has" : "has no") + " normals)");
    if (!packed) {
      exists(f.image, where + ": image");
      if (!f.depth.empty()) exists(f.depth, where + ": depth");
      if (!f.normals.empty()) exists(f.normals, where + ": normals");
    }
  }
  for (const auto& l : scene.latent_sets) {
    const std::string where = file + ": latent set " + latent_set_key(l);
    exists(l.file, where);
    FLAT_CHECK(l.height > 0 && l.width > 0 && l.height % 8 == 0 && l.width % 8 == 0,
               where + ": 'height' and 'width' must be positive multiples of 8 (the VAE downsamples by 8)");
    for (size_t i = 0; i < l.windows.size(); ++i) {
      const auto& w = l.windows[i];
      const std::string ww = where + ".windows[" + std::to_string(i) + "]";
      FLAT_CHECK(w.count >= 1 && (w.count - 1) % 4 == 0, ww + ": 'count' must be 1+4k frames, got " + std::to_string(w.count));
      FLAT_CHECK(w.count == l.frames(), ww + ": 'count' " + std::to_string(w.count) + " differs from the set's " +
                                            std::to_string(l.frames()) + " (a set holds windows of one length)");
      FLAT_CHECK(w.start >= 0 && w.start + w.count <= scene.size(),
                 ww + ": frames [" + std::to_string(w.start) + ", " + std::to_string(w.start + w.count) +
                     ") outside the scene's " + std::to_string(scene.size()) + " frames");
    }
  }
}

void write_scene_json(const Scene& scene) {
  validate_scene(scene, false);
  json doc;
  doc["format"] = "flat-scene";
  doc["version"] = kSceneFormatVersion;
  doc["name"] = scene.name;
  doc["source"] = scene.source;
  doc["metric_scale"] = scene.metric_scale;
  doc["width"] = scene.width;
  doc["height"] = scene.height;
  if (!scene.depth_source.empty()) doc["depth_source"] = scene.depth_source;
  if (!scene.normals_source.empty()) doc["normals_source"] = scene.normals_source;
  if (!scene.packed.empty()) {
    doc["packed"] = scene.packed;
    doc["packed_depth"] = scene.has_depth;
    doc["packed_normals"] = scene.has_normals;
  }
  doc["frames"] = json::array();
  for (const auto& f : scene.frames) {
    json e = camera::camera_entry(f.intrinsics, f.c2w, scene.width, scene.height);
    if (!f.image.empty()) e["image"] = f.image;
    if (!f.depth.empty()) e["depth"] = f.depth;
    if (!f.normals.empty()) e["normals"] = f.normals;
    if (f.timestamp >= 0) e["timestamp"] = f.timestamp;
    doc["frames"].push_back(std::move(e));
  }
  // scene.latents set by hand (not yet among the sets) is written as a set too.
  std::vector<LatentInfo> sets = scene.latent_sets;
  if (scene.latents.present() && !find_latent_set(scene, scene.latents.height, scene.latents.width,
                                                   scene.latents.frames())) {
    Scene with = scene;
    put_latent_set(with, scene.latents);
    sets = with.latent_sets;
  }
  if (!sets.empty()) {
    doc["latent_sets"] = json::array();
    for (const auto& set : sets) doc["latent_sets"].push_back(latents_json(set));
  }
  fs::create_directories(scene.dir);
  write_file_atomic(scene.json_path(), doc.dump(1) + "\n");
}

std::vector<std::string> scene_dirs_under(const std::string& root) {
  namespace fs = std::filesystem;
  std::error_code ec;
  if (fs::exists(fs::path(root) / kSceneFile, ec)) return {root};
  if (!fs::is_directory(root, ec)) fail(root + ": not a folder (expected a scene folder or a folder of scenes)");
  std::vector<std::string> dirs;
  for (const auto& e : fs::directory_iterator(root, ec))
    if (fs::exists(e.path() / kSceneFile, ec)) dirs.push_back(e.path().string());
  std::sort(dirs.begin(), dirs.end());
  if (dirs.empty()) fail(root + ": no scene folders (with scene.json) inside");
  return dirs;
}

}  // namespace flat::data
