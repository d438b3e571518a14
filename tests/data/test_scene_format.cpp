// Scene folders: write/read round trip, validation errors naming the file and
// key, frame loading from files and from a pack.
#include <filesystem>
#include <fstream>

#include <nlohmann/json.hpp>

#include "flat/core/error.h"
#include "flat/core/image_io.h"
#include "flat/data/pack.h"
#include "flat/data/scene.h"
#include "flat/data/scene_frames.h"
#include "flat/data/synthetic_scene.h"
#include "data_test_dirs.h"
#include "test_support.h"

using namespace flat;
namespace fs = std::filesystem;

namespace {

data::SynthScene tiny(uint64_t seed = 1) {
  data::SynthOptions o;
  o.frames = 5;
  o.height = 12;
  o.width = 16;
  o.seed = seed;
  return data::render_synthetic_scene(o);
}

nlohmann::json read_json(const fs::path& p) {
  std::ifstream in(p);
  return nlohmann::json::parse(in);
}
void write_json(const fs::path& p, const nlohmann::json& j) { std::ofstream(p) << j.dump(1); }

}  // namespace

TEST_CASE("scene folders round-trip cameras, images, depth and normals", "[data][scene]") {
  auto dir = test::fresh_dir("scene_roundtrip") / "s0";
  auto synth = tiny();
  data::write_synthetic_scene(synth, dir.string(), "s0", "test");
  auto scene = data::read_scene(dir.string());
  CHECK(scene.name == "s0");
  CHECK(scene.size() == 5);
  CHECK(scene.width == 16);
  CHECK(scene.height == 12);
  CHECK(scene.has_depth);
  CHECK(scene.has_normals);
  auto cams = scene.cameras();
  CHECK(torch::allclose(cams.c2w, synth.cameras.c2w, 1e-6, 1e-6));
  CHECK(torch::allclose(cams.intrinsics, synth.cameras.intrinsics, 1e-6, 1e-6));
  auto f = data::load_frames(scene, {4, 1}, true, true);
  CHECK(f.images.sizes() == torch::IntArrayRef({2, 3, 12, 16}));
  auto want = synth.images.index_select(0, torch::tensor({4, 1}));
  CHECK((f.images - want).abs().max().item<float>() <= 0.5f / 255 + 1e-6);  // 8-bit PNG (or U8 safetensors)
  CHECK(torch::allclose(f.depth, synth.depth.index_select(0, torch::tensor({4, 1})), 1e-6, 1e-6));
  CHECK(torch::allclose(f.normals, synth.normals.index_select(0, torch::tensor({4, 1})), 1e-6, 1e-6));

  // Packed: same frames from one safetensors file, then without the frame files.
  const std::string first_image = scene.frames[0].image;
  data::pack_scene(scene, true);
  CHECK(!fs::exists(dir / first_image));
  auto packed = data::read_scene(dir.string());
  CHECK(packed.packed == data::kPackFile);
  CHECK(packed.has_depth);
  auto g = data::load_frames(packed, {4, 1}, true, true);
  CHECK(torch::allclose(g.images, f.images, 0, 1e-6));  // both 8-bit
  CHECK(torch::equal(g.depth, f.depth));
  CHECK((g.normals - f.normals).abs().max().item<float>() < 1e-3);  // F16
}

TEST_CASE("scene validation names the file and the key at fault", "[data][scene]") {
  auto root = test::fresh_dir("scene_errors");
  auto dir = root / "bad";
  data::write_synthetic_scene(tiny(), dir.string(), "bad", "test");
  const auto json_path = dir / "scene.json";
  const auto good = read_json(json_path);

  SECTION("missing scene.json") {
    REQUIRE_THROWS_WITH(data::read_scene((root / "nothing").string()), FLAT_CONTAINS("cannot open scene file"));
  }
  SECTION("malformed JSON") {
    std::ofstream(json_path) << "{\"format\": ";
    REQUIRE_THROWS_WITH(data::read_scene(dir.string()), FLAT_CONTAINS("invalid JSON"));
  }
  SECTION("unsupported version") {
    auto j = good;
    j["version"] = 99;
    write_json(json_path, j);
    REQUIRE_THROWS_WITH(data::read_scene(dir.string()), FLAT_CONTAINS("unsupported scene format version 99"));
  }
  SECTION("missing frame file") {
    fs::remove(dir / good["frames"][2]["depth"].get<std::string>());
    REQUIRE_THROWS_WITH(data::read_scene(dir.string()), FLAT_CONTAINS("frames[2]: depth"));
  }
  SECTION("depth on some frames only") {
    auto j = good;
    j["frames"][3].erase("normals");
    write_json(json_path, j);
    REQUIRE_THROWS_WITH(data::read_scene(dir.string()), FLAT_CONTAINS("frames[3]: 'normals' must be given for every frame"));
  }
  SECTION("non-rigid camera") {
    auto j = good;
    j["frames"][1]["c2w"][0][0] = 2.0;
    write_json(json_path, j);
    REQUIRE_THROWS_WITH(data::read_scene(dir.string()), FLAT_CONTAINS("frames[1]: 'c2w' rotation is not orthonormal"));
  }
  SECTION("frame of the wrong size") {
    auto j = good;
    j["frames"][0]["width"] = 17;
    write_json(json_path, j);
    REQUIRE_THROWS_WITH(data::read_scene(dir.string()), FLAT_CONTAINS("frames[0]: size 17x12 differs"));
  }
  SECTION("latent window not 1+4k frames") {
    auto j = good;
    std::ofstream(dir / "latents.safetensors") << "x";
    j["latent_sets"] = {{{"file", "latents.safetensors"}, {"encoder", "random"}, {"height", 16}, {"width", 16},
                         {"windows", {{{"start", 0}, {"count", 4}}}}}};
    write_json(json_path, j);
    REQUIRE_THROWS_WITH(data::read_scene(dir.string()),
                        FLAT_CONTAINS("latent set 16x16_f4.windows[0]: 'count' must be 1+4k"));
  }
  SECTION("two latent sets of one size and window") {
    auto j = good;
    std::ofstream(dir / "a.safetensors") << "x";
    nlohmann::json set = {{"file", "a.safetensors"}, {"encoder", "random"}, {"height", 16}, {"width", 16},
                          {"windows", {{{"start", 0}, {"count", 5}}}}};
    j["latent_sets"] = {set, set};
    write_json(json_path, j);
    REQUIRE_THROWS_WITH(data::read_scene(dir.string()),
                        FLAT_CONTAINS("latent_sets[1]: a second set 16x16_f5"));
  }
  SECTION("a version-1 scene's one latents object is read as its one set, and written back as version 2") {
    auto j = good;
    j["version"] = 1;
    std::ofstream(dir / "latents.safetensors") << "x";
    j["latents"] = {{"file", "latents.safetensors"}, {"encoder", "random"}, {"height", 8}, {"width", 16},
                    {"windows", {{{"start", 0}, {"count", 5}}}}};
    write_json(json_path, j);
    auto scene = data::read_scene(dir.string());
    REQUIRE(scene.latent_sets.size() == 1);
    CHECK(scene.latents.present());
    CHECK(scene.latents.file == "latents.safetensors");
    CHECK(data::latent_set_key(scene.latents) == "8x16_f5");
    data::write_scene_json(scene);
    auto back = read_json(json_path);
    CHECK(back["version"] == 2);
    CHECK_FALSE(back.contains("latents"));
    CHECK(back["latent_sets"][0]["file"] == "latents.safetensors");
    CHECK(data::read_scene(dir.string()).latents.file == "latents.safetensors");
  }
  SECTION("corrupt image file fails naming it when loaded") {
    auto scene = data::read_scene(dir.string());
    std::ofstream(dir / scene.frames[1].image) << "not an image";
    REQUIRE_THROWS_WITH(data::load_frames(scene, {1}, false, false), FLAT_CONTAINS(scene.frames[1].image));
  }
}
