// Batch import (issue #43): a folder of RealEstate10K clips or nerfstudio
// scenes -> one scene per clip; bad clips skipped and reported, reruns resume.
#include <filesystem>
#include <fstream>
#include <iomanip>
#include <sstream>
#include <thread>

#include <nlohmann/json.hpp>

#include "data_test_dirs.h"
#include "flat/core/image_io.h"
#include "flat/core/npy.h"
#include "flat/data/frame_io.h"
#include "flat/data/import_batch.h"
#include "flat/data/scene.h"
#include "flat/data/scene_frames.h"
#include "flat/data/synthetic_export.h"
#include "support/read_file.h"
#include "test_support.h"

using namespace flat;
using flat::test::read_file;
namespace fs = std::filesystem;

namespace {

const bool kSingleThread = (at::set_num_threads(1), true);

constexpr int kFrames = 3;

// A RealEstate10K clip: <cams>/<name>.txt (URL line, then per frame
// "timestamp fx fy cx cy 0 0" and a row-major world-to-camera [I | t] with
// t = (id, 0.1 f, 0)) and <frames>/<name>/<timestamp>.png, every pixel (id+1)/10,
// so a clip's scene shows whose cameras and frames it got.
void write_re10k_clip(const fs::path& cams, const fs::path& frames, const std::string& name, int id) {
  fs::create_directories(cams);
  fs::create_directories(frames / name);
  std::ofstream txt(cams / (name + ".txt"));
  txt << "https://www.youtube.com/watch?v=clip" << id << "\n" << std::setprecision(17);
  for (int f = 0; f < kFrames; ++f) {
    const int64_t ts = 1000000 + 33366 * f;
    txt << ts << " 0.8 0.9 0.5 0.5 0 0  1 0 0 " << id << "  0 1 0 " << 0.1 * f << "  0 0 1 0\n";
    data::write_rgb((frames / name / (std::to_string(ts) + ".png")).string(), torch::full({3, 8, 10}, (id + 1) / 10.0));
  }
}

// The scene of clip `id` as write_re10k_clip made it: c2w = [I | -t], pixels (id+1)/10.
void check_re10k_scene(const fs::path& dir, const std::string& name, int id) {
  INFO(dir.string());
  const data::Scene s = data::read_scene(dir.string());
  CHECK(s.name == name);
  REQUIRE(s.size() == kFrames);
  for (int f = 0; f < kFrames; ++f) {
    const auto t = s.frames[size_t(f)].c2w.select(1, 3).slice(0, 0, 3);
    CHECK(torch::allclose(t, torch::tensor({-double(id), -0.1 * f, 0.0}).to(torch::kFloat), 1e-5, 1e-6));
  }
  const auto img = data::load_frames(s, {kFrames - 1}, false, false).images;
  CHECK(img.mean().item<double>() == Approx((id + 1) / 10.0).margin(1.0 / 255));
}

std::vector<std::string> staging_leftovers(const fs::path& dir) {
  std::vector<std::string> out;
  for (const auto& e : fs::directory_iterator(dir)) {
    const std::string n = e.path().filename().string();
    if (n.find(".incomplete-") != std::string::npos || n.find(".old-") != std::string::npos) out.push_back(n);
  }
  return out;
}

nlohmann::json read_summary(const fs::path& out) {
  return nlohmann::json::parse(read_file(out / "import_summary.json"));
}

// Options for a batch of RealEstate10K clips: camera files in `cams`, frames under `frames`.
data::BatchImportOptions re10k_batch(const fs::path& cams, const fs::path& frames, const fs::path& out, int jobs) {
  data::BatchImportOptions o;
  o.format = data::BatchFormat::re10k;
  o.in = cams.string();
  o.frames_root = frames.string();
  o.out_root = out.string();
  o.jobs = jobs;
  return o;
}

// Options for a batch of nerfstudio scene folders under `in`.
data::BatchImportOptions transforms_batch(const fs::path& in, const fs::path& out, int jobs) {
  data::BatchImportOptions o;
  o.format = data::BatchFormat::transforms;
  o.in = in.string();
  o.out_root = out.string();
  o.jobs = jobs;
  return o;
}

}  // namespace

TEST_CASE("batch re10k: good clips land, bad ones are reported and skipped, reruns resume", "[data][import_batch]") {
  if (!flat::image_io_available()) FLAT_SKIP("this build has no OpenImageIO: the clips' frames are PNG");
  const fs::path root = test::fresh_dir("import_batch_re10k");
  const fs::path cams = root / "cams", frames = root / "frames", out = root / "out";
  const std::vector<std::string> good = {"clip_a", "clip_b", "clip_c", "clip_d", "clip_e", "clip_f"};
  for (size_t i = 0; i < good.size(); ++i) write_re10k_clip(cams, frames, good[i], int(i));
  // A camera file cut short on its third line (its second frame line).
  write_re10k_clip(cams, frames, "bad_truncated", 7);
  {
    std::string text = read_file(cams / "bad_truncated.txt");
    std::istringstream lines(text);
    std::string a, b, c, d;
    std::getline(lines, a), std::getline(lines, b), std::getline(lines, c), std::getline(lines, d);
    std::ofstream(cams / "bad_truncated.txt") << a << "\n" << b << "\n" << c.substr(0, 20) << "\n" << d << "\n";
  }
  // A clip whose frames folder lacks its second frame.
  write_re10k_clip(cams, frames, "missing_frame", 8);
  fs::remove(frames / "missing_frame" / "1033366.png");
  // Not clips: a hidden file and a non-.txt file in the cameras folder.
  std::ofstream(cams / ".hidden.txt") << "x";
  std::ofstream(cams / "README.md") << "x";

  data::BatchImportOptions o = re10k_batch(cams, frames, out, 3);
  CHECK(data::is_batch_input(data::BatchFormat::re10k, cams.string()));
  CHECK_FALSE(data::is_batch_input(data::BatchFormat::re10k, (cams / "clip_a.txt").string()));
  const auto clips = data::list_batch_clips(o);
  REQUIRE(clips.size() == 8);
  CHECK(clips[0].name == "bad_truncated");
  CHECK(clips[0].frames == (frames / "bad_truncated").string());

  at::set_num_threads(2);
  auto r = data::import_batch(o);
  // The workers' one intra-op thread each is not left behind, for this thread
  // nor as the default of threads started later.
  CHECK(at::get_num_threads() == 2);
  int later = 0;
  std::thread([&] { later = at::get_num_threads(); }).join();
  CHECK(later == 2);
  at::set_num_threads(1);
  CHECK(r.clips == 8);
  CHECK(r.imported == 6);
  CHECK(r.present == 0);
  CHECK(r.failed == 2);
  CHECK(r.jobs == 3);
  CHECK_FALSE(r.ok());
  for (size_t i = 0; i < good.size(); ++i) check_re10k_scene(out / good[i], good[i], int(i));
  CHECK_FALSE(fs::exists(out / "bad_truncated"));
  CHECK_FALSE(fs::exists(out / "missing_frame"));
  CHECK(staging_leftovers(out).empty());

  auto summary = read_summary(out);
  CHECK(summary["format"] == "re10k");
  CHECK(summary["clips"] == 8);
  CHECK(summary["imported"] == 6);
  CHECK(summary["already_present"] == 0);
  CHECK(summary["failed"] == 2);
  CHECK(summary["seconds"].get<double>() > 0);
  CHECK(summary["clips_per_minute"].get<double>() ==
        Approx(6 * 60.0 / summary["seconds"].get<double>()).epsilon(1e-9));
  REQUIRE(summary["failures"].size() == 2);
  CHECK(summary["failures"][0]["name"] == "bad_truncated");
  CHECK(summary["failures"][0]["source"] == (cams / "bad_truncated.txt").string());
  CHECK_THAT(summary["failures"][0]["reason"].get<std::string>(),
             FLAT_CONTAINS("bad_truncated.txt: line 3: expected a timestamp and 18 numbers"));
  CHECK(summary["failures"][1]["name"] == "missing_frame");
  CHECK(summary["failures"][1]["source"] == (cams / "missing_frame.txt").string());
  CHECK_THAT(summary["failures"][1]["reason"].get<std::string>(), FLAT_CONTAINS((frames / "missing_frame").string()));
  CHECK_THAT(summary["failures"][1]["reason"].get<std::string>(), FLAT_CONTAINS("2 images but"));

  // Rerun: nothing new, the six counted as present and left alone (a file
  // put into one of them survives, as it would not if it were imported again).
  std::ofstream(out / "clip_a" / "marker.txt") << "kept";
  r = data::import_batch(o);
  CHECK(r.imported == 0);
  CHECK(r.present == 6);
  CHECK(r.failed == 2);
  CHECK(read_file(out / "clip_a" / "marker.txt") == "kept");
  summary = read_summary(out);
  CHECK(summary["imported"] == 0);
  CHECK(summary["already_present"] == 6);
  CHECK(summary["failures"].size() == 2);

  // One scene gone, and what killed runs left (staging folders of dead pids,
  // one for a clip to import, one for a clip that landed since): exactly that
  // clip is imported again, the leftovers are removed.
  fs::rename(out / "clip_c", root / "clip_c_moved_away");
  for (const char* stale : {"clip_c.incomplete-999999998", "clip_a.incomplete-999999999"}) {
    fs::create_directories(out / stale / "images");
    std::ofstream(out / stale / "images" / "000000.png") << "half";
  }
  r = data::import_batch(o);
  CHECK(r.imported == 1);
  CHECK(r.present == 5);
  CHECK(r.failed == 2);
  check_re10k_scene(out / "clip_c", "clip_c", 2);
  CHECK(staging_leftovers(out).empty());
  CHECK(read_summary(out)["imported"] == 1);

  // The broken clips repaired: they land, the batch is whole.
  write_re10k_clip(cams, frames, "bad_truncated", 7);
  write_re10k_clip(cams, frames, "missing_frame", 8);
  r = data::import_batch(o);
  CHECK(r.imported == 2);
  CHECK(r.present == 6);
  CHECK(r.failed == 0);
  CHECK(r.ok());
  check_re10k_scene(out / "missing_frame", "missing_frame", 8);
  CHECK(read_summary(out)["failures"].empty());
}

TEST_CASE("batch import: an output folder that is not a scene is reported and kept, --overwrite imports again",
          "[data][import_batch]") {
  if (!flat::image_io_available()) FLAT_SKIP("this build has no OpenImageIO: the clips' frames are PNG");
  const fs::path root = test::fresh_dir("import_batch_foreign");
  const fs::path cams = root / "cams", frames = root / "frames", out = root / "out";
  write_re10k_clip(cams, frames, "one", 0);
  write_re10k_clip(cams, frames, "two", 1);
  fs::create_directories(out / "two");
  std::ofstream(out / "two" / "notes.txt") << "the user's own file";
  data::BatchImportOptions o = re10k_batch(cams, frames, out, 2);
  auto r = data::import_batch(o);
  CHECK(r.imported == 1);
  CHECK(r.failed == 1);
  REQUIRE(r.failures.size() == 1);
  CHECK(r.failures[0].name == "two");
  CHECK_THAT(r.failures[0].reason, FLAT_CONTAINS((out / "two").string() + ": exists but is not a readable scene"));
  CHECK(read_file(out / "two" / "notes.txt") == "the user's own file");
  // --overwrite: every clip again, each replaced whole once its new scene is complete.
  std::ofstream(out / "one" / "marker.txt") << "old";
  o.import.overwrite = true;
  r = data::import_batch(o);
  CHECK(r.imported == 2);
  CHECK(r.present == 0);
  CHECK(r.ok());
  CHECK_FALSE(fs::exists(out / "one" / "marker.txt"));
  CHECK_FALSE(fs::exists(out / "two" / "notes.txt"));
  check_re10k_scene(out / "two", "two", 1);
}

TEST_CASE("batch transforms: a root of nerfstudio scene folders, one with an invalid transforms.json",
          "[data][import_batch]") {
  if (!flat::image_io_available()) FLAT_SKIP("this build has no OpenImageIO: the scenes' frames are PNG");
  const fs::path root = test::fresh_dir("import_batch_transforms");
  const fs::path in = root / "dl3dv", out = root / "out";
  // Scene k: frames with camera-to-world translation (k, 0.2 f, 0) (OpenGL axes,
  // identity rotation), images under images_4/ at a quarter of the declared
  // 40x32, every pixel (k+1)/10. s3 keeps DL3DV's benchmark layout (nerfstudio/).
  auto write_scene = [&](const fs::path& dir, int k) {
    fs::create_directories(dir / "images_4");
    nlohmann::json doc = {{"w", 40}, {"h", 32}, {"fl_x", 30}, {"fl_y", 30}, {"cx", 20}, {"cy", 16}};
    doc["frames"] = nlohmann::json::array();
    for (int f = 0; f < kFrames; ++f) {
      const std::string file = "images_4/frame_" + std::to_string(f) + ".png";
      data::write_rgb((dir / file).string(), torch::full({3, 8, 10}, (k + 1) / 10.0));
      doc["frames"].push_back({{"file_path", file},
                               {"transform_matrix", {{1, 0, 0, k}, {0, 1, 0, 0.2 * f}, {0, 0, 1, 0}, {0, 0, 0, 1}}}});
    }
    std::ofstream(dir / "transforms.json") << doc.dump();
  };
  write_scene(in / "s1", 1);
  write_scene(in / "s2", 2);
  write_scene(in / "s3" / "nerfstudio", 3);
  write_scene(in / "broken", 4);
  std::ofstream(in / "broken" / "transforms.json") << "{\"frames\": [ {\"file_path\": ";  // cut short
  fs::create_directories(in / ".cache");  // hidden: not a scene

  CHECK(data::is_batch_input(data::BatchFormat::transforms, in.string()));
  CHECK_FALSE(data::is_batch_input(data::BatchFormat::transforms, (in / "s1").string()));  // one scene
  CHECK_FALSE(data::is_batch_input(data::BatchFormat::transforms, (in / "s1" / "transforms.json").string()));

  data::BatchImportOptions o = transforms_batch(in, out, 2);
  auto r = data::import_batch(o);
  CHECK(r.clips == 4);
  CHECK(r.imported == 3);
  CHECK(r.failed == 1);
  CHECK_FALSE(r.ok());
  for (int k = 1; k <= 3; ++k) {
    const std::string name = "s" + std::to_string(k);
    INFO(name);
    const data::Scene s = data::read_scene((out / name).string());
    CHECK(s.name == name);
    REQUIRE(s.size() == kFrames);
    CHECK(s.width == 10);
    CHECK(s.height == 8);
    // OpenGL -> OpenCV negates the y and z axes of the camera, not the translation.
    CHECK(s.frames[2].c2w[0][3].item<float>() == Approx(k));
    CHECK(s.frames[2].c2w[1][3].item<float>() == Approx(0.4));
    CHECK(s.frames[2].c2w[1][1].item<float>() == Approx(-1));
    CHECK(data::load_frames(s, {1}, false, false).images.mean().item<double>() == Approx((k + 1) / 10.0).margin(1.0 / 255));
  }
  CHECK_FALSE(fs::exists(out / "broken"));
  CHECK_FALSE(fs::exists(out / ".cache"));
  auto summary = read_summary(out);
  CHECK(summary["format"] == "transforms");
  REQUIRE(summary["failures"].size() == 1);
  CHECK(summary["failures"][0]["name"] == "broken");
  CHECK(summary["failures"][0]["source"] == (in / "broken" / "transforms.json").string());
  CHECK_THAT(summary["failures"][0]["reason"].get<std::string>(),
             FLAT_CONTAINS((in / "broken" / "transforms.json").string() + ": invalid JSON"));

  // Rerun after removing one output scene: only that one is imported.
  fs::rename(out / "s2", root / "s2_moved_away");
  r = data::import_batch(o);
  CHECK(r.imported == 1);
  CHECK(r.present == 2);
  CHECK(r.failed == 1);
  CHECK(data::read_scene((out / "s2").string()).size() == kFrames);
}

TEST_CASE("batch import: an empty input folder or a missing frames root stops the batch, naming the folder",
          "[data][import_batch]") {
  const fs::path root = test::fresh_dir("import_batch_empty");
  fs::create_directories(root / "cams");
  fs::create_directories(root / "frames");
  data::BatchImportOptions o;
  o.in = (root / "cams").string();
  o.frames_root = (root / "frames").string();
  o.out_root = (root / "out").string();
  REQUIRE_THROWS_WITH(data::import_batch(o), FLAT_CONTAINS((root / "cams").string() + ": no <clip>.txt camera files"));
  o.frames_root = (root / "no_frames").string();
  REQUIRE_THROWS_WITH(data::import_batch(o), FLAT_CONTAINS((root / "no_frames").string() + ": not a folder"));
  o.format = data::BatchFormat::transforms;
  REQUIRE_THROWS_WITH(data::import_batch(o), FLAT_CONTAINS("no scene folders"));
  CHECK_FALSE(fs::exists(root / "out" / "import_summary.json"));
}

TEST_CASE("batch import with depth maps: the depth option is a root of per-clip folders", "[data][import_batch]") {
  if (!flat::image_io_available()) FLAT_SKIP("this build has no OpenImageIO: the clips' frames are PNG");
  const fs::path root = test::fresh_dir("import_batch_depth");
  const fs::path cams = root / "cams", frames = root / "frames", depth = root / "depth", out = root / "out";
  write_re10k_clip(cams, frames, "g1", 0);
  write_re10k_clip(cams, frames, "g2", 1);
  write_re10k_clip(cams, frames, "g3", 2);
  // Depth maps of g1 (1.5 m) and g3 (4 m); g2 has no folder under the root.
  for (const auto& [name, metres] : {std::pair<std::string, double>{"g1", 1.5}, {"g3", 4.0}})
    for (int f = 0; f < kFrames; ++f)
      // .npy: read by every build (EXR needs OpenImageIO).
      flat::write_npy((depth / name / (std::to_string(1000000 + 33366 * f) + ".npy")).string(),
                      torch::full({8, 10}, metres));
  data::BatchImportOptions o = re10k_batch(cams, frames, out, 2);
  o.import.geometry.depth_dir = depth.string();
  auto r = data::import_batch(o);
  CHECK(r.imported == 2);
  REQUIRE(r.failures.size() == 1);
  CHECK(r.failures[0].name == "g2");
  CHECK_THAT(r.failures[0].reason, FLAT_CONTAINS((depth / "g2").string() + ": no depth folder for clip 'g2'"));
  CHECK_FALSE(fs::exists(out / "g2"));
  // Each clip got its own folder's maps (not the root, not another clip's).
  for (const auto& [name, metres] : {std::pair<std::string, double>{"g1", 1.5}, {"g3", 4.0}}) {
    INFO(name);
    const data::Scene s = data::read_scene((out / name).string());
    CHECK(s.has_depth);
    CHECK_THAT(s.depth_source, FLAT_CONTAINS((depth / name).string()));
    auto d = data::load_frames(s, {1}, true, false).depth;
    CHECK(d.mean().item<double>() == Approx(metres).epsilon(1e-5));
  }
}

TEST_CASE("batch import: {clip} in --depth / --normals finds maps inside each DL3DV scene folder",
          "[data][import_batch]") {
  CHECK(data::clip_maps_folder("maps", "c1") == (fs::path("maps") / "c1").string());
  CHECK(data::clip_maps_folder("raw/{clip}/depth", "c1") == "raw/c1/depth");
  CHECK(data::clip_maps_folder("a/{clip}/b_{clip}", "{clip}x") == "a/{clip}x/b_{clip}x");
  CHECK(data::clip_maps_folder("", "c1").empty());
  if (!flat::image_io_available()) FLAT_SKIP("this build has no OpenImageIO: the scenes' frames are PNG");
  // flat_synth --format dl3dv: <scene>/images_4/, <scene>/depth/*.png (16-bit,
  // millimetres of the unit), <scene>/normals/*.npy (OpenGL), <scene>/truth/.
  const fs::path root = test::fresh_dir("import_batch_clip_placeholder");
  const fs::path in = root / "dl3dv", out = root / "out";
  data::SynthExportOptions e;
  e.format = "dl3dv";
  e.count = 3;
  e.seed = 5;
  e.unit = 0.25;
  e.synth.frames = 3;
  e.synth.height = 16;
  e.synth.width = 24;
  const auto exported = data::export_synthetic(e, in.string());
  REQUIRE(exported.size() == 3);
  const auto manifest = nlohmann::json::parse(read_file(in / "manifest.json"));
  const std::string batch_line = manifest["import"]["batch"];
  CHECK_THAT(batch_line, FLAT_CONTAINS("--depth 'ROOT/{clip}/depth' --depth-png-scale 0.001"));
  CHECK_THAT(batch_line, FLAT_CONTAINS("--normals 'ROOT/{clip}/normals' --normals-convention opengl"));
  // The third scene lost its normals folder: that clip fails, naming the folder and the pattern.
  const std::string lost = exported[2].name;
  fs::rename(in / lost / "normals", root / "normals_moved_away");

  data::BatchImportOptions o = transforms_batch(in, out, 2);
  o.import.metric_scale = e.unit;
  o.import.geometry.depth_dir = (in / "{clip}" / "depth").string();
  o.import.geometry.depth_png_scale = 0.001;
  o.import.geometry.normals_dir = (in / "{clip}" / "normals").string();
  o.import.geometry.normals_convention = "opengl";
  auto r = data::import_batch(o);
  CHECK(r.clips == 3);
  CHECK(r.imported == 2);
  REQUIRE(r.failures.size() == 1);
  CHECK(r.failures[0].name == lost);
  CHECK_THAT(r.failures[0].reason, FLAT_CONTAINS((in / lost / "normals").string() + ": no normals folder for clip '" +
                                                 lost + "' (the normals option '" + o.import.geometry.normals_dir));
  CHECK_FALSE(fs::exists(out / lost));
  // Each scene got its own folder's maps: metric depth (code * 0.001 * unit)
  // within half a code of the truth, normals converted to OpenCV.
  for (size_t i = 0; i < 2; ++i) {
    const std::string name = exported[i].name;
    INFO(name);
    const data::Scene s = data::read_scene((out / name).string());
    REQUIRE(s.size() == 3);
    CHECK(s.has_depth);
    CHECK(s.has_normals);
    CHECK_THAT(s.depth_source, FLAT_CONTAINS((in / name / "depth").string()));
    CHECK_THAT(s.normals_source, FLAT_CONTAINS((in / name / "normals").string()));
    const data::Scene truth = data::read_scene((in / name / "truth").string());
    auto got = data::load_frames(s, {0, 1, 2}, true, true);
    auto want = data::load_frames(truth, {0, 1, 2}, true, true);
    CHECK((got.depth - want.depth).abs().max().item<double>() <= 0.5e-3 * e.unit + 1e-5);
    CHECK((got.normals - want.normals).abs().max().item<double>() < 1e-4);
  }
  // The scene repaired, a rerun imports just it.
  fs::rename(root / "normals_moved_away", in / lost / "normals");
  r = data::import_batch(o);
  CHECK(r.imported == 1);
  CHECK(r.present == 2);
  CHECK(r.ok());
  CHECK(data::read_scene((out / lost).string()).has_normals);
}
