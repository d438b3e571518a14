#include <fstream>

#include "flat/camera/camera_json.h"
#include "flat/core/error.h"
#include "test_support.h"

using namespace flat::camera;

namespace {
std::string write_text(const std::filesystem::path& dir, const std::string& name, const std::string& text) {
  auto p = (dir / name).string();
  std::ofstream(p) << text;
  return p;
}
const char* kGood = R"({"version": 1, "cameras": [
  {"width": 8, "height": 6, "intrinsics": [1.0, 1.2, 0.5, 0.5],
   "c2w": [[1,0,0,0.5],[0,1,0,-1],[0,0,1,2],[0,0,0,1]]},
  {"width": 8, "height": 6, "intrinsics": [0.9, 1.1, 0.45, 0.55],
   "c2w": [[0,0,1,0],[0,1,0,0],[-1,0,0,0],[0,0,0,1]]}]})";
}  // namespace

TEST_CASE("cameras JSON reads, writes and reads back identically", "[camera]") {
  auto dir = flat::test::scratch_dir("camera_json");
  auto set = read_cameras_json(write_text(dir, "good.json", kGood));
  REQUIRE(set.cameras.size() == 2);
  CHECK(set.width == 8);
  CHECK(set.height == 6);
  CHECK(set.cameras.intrinsics[1][3].item<float>() == Approx(0.55));
  CHECK(set.cameras.c2w[0][1][3].item<float>() == Approx(-1.0));
  auto out = (dir / "again.json").string();
  write_cameras_json(out, set);
  auto back = read_cameras_json(out);
  CHECK(at::equal(back.cameras.intrinsics, set.cameras.intrinsics));
  CHECK(at::equal(back.cameras.c2w, set.cameras.c2w));
}

TEST_CASE("cameras JSON errors name the file, the entry and the problem", "[camera]") {
  auto dir = flat::test::scratch_dir("camera_json_bad");
  struct Row { const char* text; const char* expected; };
  const Row rows[] = {
      {"{not json", "invalid JSON"},
      {R"({"cams": []})", "'cameras' array"},
      {R"({"cameras": []})", "'cameras' is empty"},
      {R"({"version": 2, "cameras": [{}]})", "unsupported cameras file version"},
      {R"({"cameras": [{"width": 8, "height": 6, "intrinsics": [1,1,0.5]}]})", "cameras[0]: missing key 'c2w'"},
      {R"({"cameras": [{"width": 8, "height": 6, "intrinsics": [1,1,0.5], "c2w": []}]})", "'intrinsics' must be"},
      {R"({"cameras": [{"width": -8, "height": 6, "intrinsics": [1,1,0.5,0.5], "c2w": []}]})", "positive integers"},
      {R"({"cameras": [{"width": 8, "height": 6, "intrinsics": [0,1,0.5,0.5],
          "c2w": [[1,0,0,0],[0,1,0,0],[0,0,1,0],[0,0,0,1]]}]})", "focal lengths"},
      {R"({"cameras": [{"width": 8, "height": 6, "intrinsics": [1,1,0.5,0.5],
          "c2w": [[2,0,0,0],[0,1,0,0],[0,0,1,0],[0,0,0,1]]}]})", "not orthonormal"},
      {R"({"cameras": [{"width": 8, "height": 6, "intrinsics": [1,1,0.5,0.5],
          "c2w": [[1,0,0,"x"],[0,1,0,0],[0,0,1,0],[0,0,0,1]]}]})", "'c2w' must hold numbers"},
      {R"({"cameras": [{"width": 8, "height": 6, "intrinsics": [1,1,0.5,0.5],
          "c2w": [[1,0,0,0],[0,1,0,0],[0,0,1,0],[0,0,0,1]]},
          {"width": 9, "height": 6, "intrinsics": [1,1,0.5,0.5],
          "c2w": [[1,0,0,0],[0,1,0,0],[0,0,1,0],[0,0,0,1]]}]})", "cameras[1]: size 9x6 differs"},
  };
  int i = 0;
  for (const auto& row : rows) {
    auto path = write_text(dir, "bad" + std::to_string(i++) + ".json", row.text);
    INFO(row.text);
    REQUIRE_THROWS_WITH(read_cameras_json(path), FLAT_CONTAINS(row.expected) && FLAT_CONTAINS(path));
  }
  REQUIRE_THROWS_WITH(read_cameras_json((dir / "missing.json").string()), FLAT_CONTAINS("cannot open"));
}
