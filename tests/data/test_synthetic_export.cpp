// flat_synth's export mode (issue #43): rooms written as RealEstate10K clips
// and DL3DV (nerfstudio) scenes, checked against the rooms' ground truth with
// readers written here (camera text, NPY, transforms.json), then imported with
// the project's importers, and the corrupt clips checked against the manifest.
#include "flat/data/synthetic_export.h"

#include <algorithm>
#include <cstring>
#include <fstream>
#include <map>
#include <sstream>

#include <nlohmann/json.hpp>

#include "flat/camera/cameras.h"
#include "flat/core/error.h"
#include "flat/core/image_io.h"
#include "flat/data/importers.h"
#include "flat/data/scene.h"
#include "data_test_dirs.h"
#include "test_support.h"

using namespace flat;
using nlohmann::json;
namespace fs = std::filesystem;

namespace {

constexpr int64_t kH = 32, kW = 48, kF = 5;

data::SynthExportOptions export_opts(const std::string& format, uint64_t seed, int64_t count, int64_t corrupt) {
  data::SynthExportOptions o;
  o.format = format;
  o.seed = seed;
  o.count = count;
  o.corrupt = corrupt;
  o.unit = 0.5;
  o.synth.family = "room";
  o.synth.motion = "mixed";
  o.synth.frames = kF;
  o.synth.height = kH;
  o.synth.width = kW;
  return o;
}

json read_json(const fs::path& p) {
  std::ifstream in(p);
  REQUIRE(in);
  return json::parse(in);
}

std::string read_text(const fs::path& p) {
  std::ifstream in(p, std::ios::binary);
  std::stringstream s;
  s << in.rdbuf();
  return s.str();
}

// The room behind a manifest entry, rendered again from the seed it names.
data::SynthScene truth_of(const json& manifest, const json& clip) {
  data::SynthOptions s;
  s.family = manifest["family"].get<std::string>();
  s.motion = manifest["motion"].get<std::string>();
  s.frames = manifest["frames"].get<int64_t>();
  s.height = manifest["height"].get<int64_t>();
  s.width = manifest["width"].get<int64_t>();
  s.seed = clip["synth_seed"].get<uint64_t>();
  return data::render_synthetic_scene(s);
}

// A minimal NPY v1 reader, independent of the writer: '<f4', C order.
torch::Tensor read_npy(const fs::path& p) {
  const std::string bytes = read_text(p);
  REQUIRE(bytes.size() >= 10);
  REQUIRE(bytes.compare(0, 6, "\x93NUMPY") == 0);
  REQUIRE(bytes[6] == 1);
  REQUIRE(bytes[7] == 0);
  const size_t len = size_t(uint8_t(bytes[8])) | (size_t(uint8_t(bytes[9])) << 8);
  REQUIRE((10 + len) % 64 == 0);
  const std::string dict = bytes.substr(10, len);
  REQUIRE(dict.back() == '\n');
  REQUIRE(dict.find("'descr': '<f4'") != std::string::npos);
  REQUIRE(dict.find("'fortran_order': False") != std::string::npos);
  const size_t open = dict.find("'shape': ("), close = dict.find(')', open);
  REQUIRE(open != std::string::npos);
  std::vector<int64_t> shape;
  std::stringstream dims(dict.substr(open + 10, close - open - 10));
  std::string d;
  while (std::getline(dims, d, ','))
    if (d.find_first_not_of(' ') != std::string::npos) shape.push_back(std::stoll(d));
  int64_t n = 1;
  for (auto v : shape) n *= v;
  REQUIRE(bytes.size() == 10 + len + size_t(n) * 4);
  auto t = torch::empty(shape, torch::kFloat);
  std::memcpy(t.data_ptr<float>(), bytes.data() + 10 + len, size_t(n) * 4);
  return t;
}

struct CameraLine {
  std::string timestamp;
  std::vector<double> values;
};

// RealEstate10K camera text, parsed here: the URL line, then whitespace-separated numbers.
std::vector<CameraLine> read_camera_file(const fs::path& p, std::string* url = nullptr) {
  std::ifstream in(p);
  REQUIRE(in);
  std::string line;
  REQUIRE(std::getline(in, line));
  if (url) *url = line;
  std::vector<CameraLine> out;
  while (std::getline(in, line)) {
    std::istringstream s(line);
    CameraLine c;
    s >> c.timestamp;
    double v;
    while (s >> v) c.values.push_back(v);
    out.push_back(c);
  }
  return out;
}

double max_abs(const torch::Tensor& a, const torch::Tensor& b) {
  return (a.to(torch::kDouble) - b.to(torch::kDouble)).abs().max().item<double>();
}

// OpenCV camera-space normals (3,H,W) -> OpenGL: y and z negated.
torch::Tensor gl(const torch::Tensor& n) { return torch::stack({n[0], -n[1], -n[2]}); }

// The largest |R^T R - I| of a 3x3 block.
double orthonormality_error(const torch::Tensor& R) {
  auto r = R.to(torch::kDouble);
  return (torch::matmul(r.t(), r) - torch::eye(3, torch::kDouble)).abs().max().item<double>();
}

}  // namespace

TEST_CASE("synthetic export re10k: cameras, frames, depth and normals decode to the room's truth",
          "[data][synthetic_export]") {
  if (!image_io_available()) FLAT_SKIP("built without image IO");
  const fs::path root = test::fresh_dir("export_re10k") / "re10k";
  auto o = export_opts("re10k", 3, 2, 0);
  auto clips = data::export_synthetic(o, root.string());
  REQUIRE(clips.size() == 2);
  const json m = read_json(root / "manifest.json");
  CHECK(m["unit"].get<double>() == 0.5);
  CHECK(m["export_format"] == "re10k");
  CHECK(m["corrupt"].empty());
  REQUIRE(m["clips"].size() == 2);
  CHECK_FALSE(fs::exists(root.string() + ".incomplete-" + std::to_string(::getpid())));
  for (size_t c = 0; c < 2; ++c) {
    const json& clip = m["clips"][c];
    const std::string name = clip["name"];
    INFO("clip " << name);
    CHECK(name.size() == 16);
    CHECK(clip["name"] == clips[c].name);
    CHECK(clip["synth_seed"].get<uint64_t>() == 3ull * 1000003ull + c);  // flat_synth's scene c of seed 3
    CHECK(clip["corrupt"].is_null());
    auto truth = truth_of(m, clip);
    const double unit = m["unit"];

    std::string url;
    auto lines = read_camera_file(root / clip["camera_file"].get<std::string>(), &url);
    CHECK(url.rfind("https://www.youtube.com/watch?v=", 0) == 0);
    REQUIRE(int64_t(lines.size()) == kF);
    auto w2c = camera::world_to_camera(truth.cameras.c2w).to(torch::kDouble);
    for (int64_t f = 0; f < kF; ++f) {
      const auto& l = lines[size_t(f)];
      REQUIRE(l.values.size() == 18);
      CHECK(l.timestamp == clip["timestamps"][size_t(f)].get<std::string>());
      if (f > 0) {  // 29.97 fps in microseconds
        const long long step = std::stoll(l.timestamp) - std::stoll(lines[size_t(f - 1)].timestamp);
        CHECK((step == 33366 || step == 33367));
      }
      auto intr = torch::tensor(std::vector<double>(l.values.begin(), l.values.begin() + 4), torch::kDouble);
      CHECK(max_abs(intr, truth.cameras.intrinsics[f]) < 1e-6);
      CHECK(l.values[4] == 0);
      CHECK(l.values[5] == 0);
      auto got = torch::tensor(std::vector<double>(l.values.begin() + 6, l.values.end()), torch::kDouble).view({3, 4});
      auto want = w2c[f].slice(0, 0, 3).clone();
      want.select(1, 3).div_(unit);  // translations in units of `unit` metres
      CHECK(max_abs(got, want) < 1e-5);
      CHECK(want.select(1, 3).abs().max().item<double>() > 0.5);  // the unit matters here

      const std::string ts = l.timestamp;
      auto rgb = read_image((root / "frames" / name / (ts + ".png")).string());
      CHECK(max_abs(rgb, truth.images[f]) <= 0.5 / 255 + 1e-6);
      auto depth = read_npy(root / "depth" / name / (ts + ".npy"));
      REQUIRE(depth.sizes() == torch::IntArrayRef({kH, kW}));
      CHECK(max_abs(depth * unit, truth.depth[f][0]) < 1e-5);
      CHECK(truth.depth[f].min().item<float>() > 0);  // a closed room: every pixel known
      auto normals = read_image((root / "normals" / name / (ts + ".png")).string());
      REQUIRE(normals.sizes() == torch::IntArrayRef({3, kH, kW}));
      auto n = normals * 2 - 1;
      CHECK(max_abs(n, gl(truth.normals[f])) <= 1.0 / 255 + 1e-6);
      CHECK(max_abs(n, truth.normals[f]) > 0.5);  // the y/z flip is visible at this tolerance
    }

    // The rehearsal: the importer with --scale unit gives back the metric cameras.
    data::ImportOptions io;
    io.metric_scale = unit;
    auto scene = data::import_re10k((root / clip["camera_file"].get<std::string>()).string(),
                                    (root / clip["frames_dir"].get<std::string>()).string(),
                                    (root.parent_path() / ("import_" + name)).string(), io);
    REQUIRE(scene.size() == kF);
    auto cams = scene.cameras();
    CHECK(max_abs(cams.c2w, truth.cameras.c2w) < 1e-4);
    CHECK(max_abs(cams.intrinsics, truth.cameras.intrinsics) < 1e-6);
    // The truth folder holds the same metric cameras.
    auto t = data::read_scene((root / clip["truth"].get<std::string>()).string());
    CHECK(max_abs(t.cameras().c2w, truth.cameras.c2w) < 1e-6);
  }
}

TEST_CASE("synthetic export dl3dv: transforms.json, PNG16 depth and NPY normals decode to the room's truth",
          "[data][synthetic_export]") {
  if (!image_io_available()) FLAT_SKIP("built without image IO");
  const fs::path root = test::fresh_dir("export_dl3dv") / "dl3dv";
  auto o = export_opts("dl3dv", 4, 2, 0);
  o.unit = 0.25;
  data::export_synthetic(o, root.string());
  const json m = read_json(root / "manifest.json");
  REQUIRE(m["clips"].size() == 2);
  const double unit = m["unit"];
  CHECK(unit == 0.25);
  for (const json& clip : m["clips"]) {
    const std::string name = clip["name"];
    INFO("scene " << name);
    CHECK(name.size() == 64);
    auto truth = truth_of(m, clip);
    const json doc = read_json(root / name / "transforms.json");
    CHECK(doc["w"].get<double>() == 4 * kW);  // DL3DV: full-resolution intrinsics, images_4 stored
    CHECK(doc["h"].get<double>() == 4 * kH);
    auto k = truth.cameras.intrinsics[0].to(torch::kDouble);
    CHECK(std::abs(doc["fl_x"].get<double>() / (4 * kW) - k[0].item<double>()) < 1e-7);
    CHECK(std::abs(doc["fl_y"].get<double>() / (4 * kH) - k[1].item<double>()) < 1e-7);
    CHECK(std::abs(doc["cx"].get<double>() - 2 * kW) < 1e-6);
    CHECK(std::abs(doc["cy"].get<double>() - 2 * kH) < 1e-6);
    REQUIRE(int64_t(doc["frames"].size()) == kF);
    for (int64_t f = 0; f < kF; ++f) {
      const json& fr = doc["frames"][size_t(f)];
      char stem[32];
      std::snprintf(stem, sizeof(stem), "frame_%05lld", static_cast<long long>(f + 1));
      CHECK(fr["file_path"] == std::string("images_4/") + stem + ".png");
      auto got = torch::empty({4, 4}, torch::kDouble);
      for (int r = 0; r < 4; ++r)
        for (int c = 0; c < 4; ++c) got[r][c] = fr["transform_matrix"][size_t(r)][size_t(c)].get<double>();
      // OpenGL camera-to-world: OpenCV's with the y and z columns negated, translation in units.
      auto want = truth.cameras.c2w[f].to(torch::kDouble).clone();
      want.select(1, 1).neg_();
      want.select(1, 2).neg_();
      want.select(1, 3).slice(0, 0, 3).div_(unit);
      CHECK(max_abs(got, want) < 1e-5);

      auto rgb = read_image((root / name / "images_4" / (std::string(stem) + ".png")).string());
      REQUIRE(rgb.sizes() == torch::IntArrayRef({3, kH, kW}));
      CHECK(max_abs(rgb, truth.images[f]) <= 0.5 / 255 + 1e-6);
      // 16-bit PNG: round(depth_m * 1000 / unit), i.e. within half a millimetre of the unit.
      auto code = torch::round(read_image((root / name / "depth" / (std::string(stem) + ".png")).string()) * 65535.0);
      REQUIRE(code.sizes() == torch::IntArrayRef({1, kH, kW}));
      auto want_code = torch::round(truth.depth[f].to(torch::kDouble) * (1000.0 / unit));
      CHECK(max_abs(code, want_code) == 0);
      CHECK(max_abs(code.to(torch::kDouble) * unit / 1000.0, truth.depth[f]) <= 0.5e-3 * unit + 1e-6);
      auto normals = read_npy(root / name / "normals" / (std::string(stem) + ".npy"));
      REQUIRE(normals.sizes() == torch::IntArrayRef({kH, kW, 3}));
      CHECK(max_abs(normals.permute({2, 0, 1}), gl(truth.normals[f])) < 1e-7);
      CHECK(max_abs(normals.permute({2, 0, 1}), truth.normals[f]) > 0.5);
    }
    // The rehearsal: import with --scale unit restores the metric OpenCV cameras.
    data::ImportOptions io;
    io.metric_scale = unit;
    auto scene = data::import_transforms_json((root / name).string(), (root.parent_path() / ("import_" + name)).string(), io);
    REQUIRE(scene.size() == kF);
    auto cams = scene.cameras();
    CHECK(max_abs(cams.c2w, truth.cameras.c2w) < 1e-4);
    CHECK(max_abs(cams.intrinsics, truth.cameras.intrinsics) < 1e-6);
    // The truth folder sits inside the scene folder (a batch import of ROOT sees only scenes).
    CHECK(clip["truth"] == name + "/truth");
    auto t = data::read_scene((root / clip["truth"].get<std::string>()).string());
    CHECK(max_abs(t.cameras().c2w, truth.cameras.c2w) < 1e-6);
  }
}

TEST_CASE("synthetic export --corrupt: exactly the clips the manifest names are corrupt, as it says",
          "[data][synthetic_export]") {
  if (!image_io_available()) FLAT_SKIP("built without image IO");
  const fs::path dir = test::fresh_dir("export_corrupt");
  std::map<std::string, int> kinds_seen;
  for (const std::string format : {"re10k", "dl3dv"})
    for (int64_t corrupt : {1, 2}) {
      const fs::path root = dir / (format + std::to_string(corrupt));
      auto o = export_opts(format, 9, 2, corrupt);
      auto clips = data::export_synthetic(o, root.string());
      const json m = read_json(root / "manifest.json");
      REQUIRE(int64_t(m["corrupt"].size()) == corrupt);
      int64_t flagged = 0;
      for (size_t c = 0; c < clips.size(); ++c) {
        const json& clip = m["clips"][c];
        const std::string name = clip["name"];
        const bool listed = std::find(m["corrupt"].begin(), m["corrupt"].end(), name) != m["corrupt"].end();
        INFO(format << " corrupt " << corrupt << " clip " << name);
        CHECK(listed == !clip["corrupt"].is_null());
        CHECK(listed == !clips[c].corrupt.empty());
        flagged += listed;
        const std::string kind = listed ? clip["corrupt"]["kind"].get<std::string>() : "";
        if (listed) ++kinds_seen[kind];
        data::ImportOptions io;
        io.metric_scale = m["unit"].get<double>();
        const std::string out = (dir / ("import_" + format + std::to_string(corrupt) + "_" + name)).string();
        if (format == "re10k") {
          const fs::path cam = root / clip["camera_file"].get<std::string>();
          auto lines = read_camera_file(cam);
          const fs::path frames = root / clip["frames_dir"].get<std::string>();
          int64_t short_lines = 0, missing = 0;
          for (const auto& l : lines) short_lines += l.values.size() != 18;
          for (const auto& ts : clip["timestamps"]) missing += !fs::exists(frames / (ts.get<std::string>() + ".png"));
          CHECK(short_lines == (kind == "truncated_line" ? 1 : 0));
          CHECK(missing == (kind == "missing_frame" ? 1 : 0));
          if (kind == "truncated_line") {
            const auto& l = lines[size_t(clip["corrupt"]["frame"].get<int64_t>())];
            CHECK(l.timestamp == clip["corrupt"]["timestamp"].get<std::string>());
            CHECK(l.values.size() < 18);
          }
          if (kind == "missing_frame")
            CHECK_FALSE(fs::exists(frames / (clip["corrupt"]["timestamp"].get<std::string>() + ".png")));
          if (listed)
            CHECK_THROWS_AS(data::import_re10k(cam.string(), frames.string(), out, io), Error);
          else
            CHECK(data::import_re10k(cam.string(), frames.string(), out, io).size() == kF);
        } else {
          const fs::path tj = root / name / "transforms.json";
          json doc;
          bool parses = true;
          try {
            doc = json::parse(read_text(tj));
          } catch (const json::exception&) {
            parses = false;
          }
          CHECK(parses == (kind != "truncated_json"));
          int64_t bad_rotations = 0;
          if (parses)
            for (size_t f = 0; f < doc["frames"].size(); ++f) {
              auto R = torch::empty({3, 3}, torch::kDouble);
              for (int r = 0; r < 3; ++r)
                for (int c2 = 0; c2 < 3; ++c2) R[r][c2] = doc["frames"][f]["transform_matrix"][size_t(r)][size_t(c2)].get<double>();
              if (orthonormality_error(R) > 1e-6) {
                ++bad_rotations;
                CHECK(int64_t(f) == clip["corrupt"]["frame"].get<int64_t>());
              }
            }
          CHECK(bad_rotations == (kind == "non_orthonormal" ? 1 : 0));
          if (listed)
            CHECK_THROWS_AS(data::import_transforms_json((root / name).string(), out, io), Error);
          else
            CHECK(data::import_transforms_json((root / name).string(), out, io).size() == kF);
        }
      }
      CHECK(flagged == corrupt);
      // Deterministic by seed: the same clips and kinds again.
      if (corrupt == 1) {
        auto again = data::export_synthetic(o, (dir / (format + "_again")).string());
        for (size_t c = 0; c < clips.size(); ++c) {
          CHECK(again[c].name == clips[c].name);
          CHECK(again[c].corrupt == clips[c].corrupt);
        }
      }
    }
  // --corrupt 2 of 2 gives both kinds of each format.
  for (const char* kind : {"truncated_line", "missing_frame", "truncated_json", "non_orthonormal"}) {
    INFO(kind);
    CHECK(kinds_seen[kind] >= 1);
  }
}

TEST_CASE("synthetic export refuses an existing root and bad options before rendering", "[data][synthetic_export]") {
  if (!image_io_available()) FLAT_SKIP("built without image IO");
  const fs::path root = test::fresh_dir("export_refuse");
  auto o = export_opts("re10k", 1, 1, 0);
  int frames = 0;
  o.synth.on_frame = [&] { ++frames; };
  CHECK_THROWS_AS(data::export_synthetic(o, root.string()), Error);  // exists (an empty scratch folder)
  CHECK(frames == 0);
  o.corrupt = 2;
  CHECK_THROWS_AS(data::export_synthetic(o, (root / "x").string()), Error);
  o.corrupt = 0;
  o.format = "colmap";
  CHECK_THROWS_AS(data::export_synthetic(o, (root / "x").string()), Error);
  o.format = "re10k";
  o.unit = 0;
  CHECK_THROWS_AS(data::export_synthetic(o, (root / "x").string()), Error);
  CHECK(frames == 0);
  CHECK_FALSE(fs::exists(root / "x"));
}
