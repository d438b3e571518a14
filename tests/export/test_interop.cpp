// Our PLY and GLB read by other programs (trimesh, assimp, Blender) through
// scripts/check_interop.py. Hidden tag: run by its own CTest entry
// (export_interop, tests/CMakeLists.txt), since Blender takes seconds to start.
// With FLAT_INTEROP_REQUIRE_ALL=1 (CI) every reader must be present.
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <sstream>
#include <string>
#include <vector>

#include <torch/torch.h>

#include "flat/export/mesh_files.h"
#include "flat/export/triangle_glb.h"
#include "flat/export/triangle_ply.h"
#include "support/process.h"
#include "render/render_scenes.h"
#include "test_support.h"

namespace {

// FLAT_INTEROP_REQUIRE_ALL=1 (CI): every reader must be there.
bool interop_required() {
  const char* env = std::getenv("FLAT_INTEROP_REQUIRE_ALL");
  return env && std::string(env) == "1";
}

// The venv of scripts/install_deps.sh holds trimesh; any python3 runs the
// script. "" when there is none, which fails where every reader is required.
std::string interop_python() {
  const char* home = std::getenv("HOME");
  std::string python = home ? std::string(home) + "/.cache/flat/venv/bin/python3" : "";
  if (python.empty() || !std::filesystem::exists(python)) python = flat::test::find_program("python3");
  if (python.empty()) REQUIRE_FALSE(interop_required());
  return python;
}

// scripts/check_interop.py `args` (plus --require-all in CI) run by `python`,
// its log in `dir`: the report is printed, and the run must pass with no
// MISMATCH. Returns the report.
std::string check_interop(const std::string& python, std::vector<std::string> args, const std::filesystem::path& dir,
                          const std::string& label) {
  const bool require_all = interop_required();
  args.insert(args.begin(), {python, std::string(FLAT_SOURCE_DIR) + "/scripts/check_interop.py"});
  if (require_all) args.push_back("--require-all");
  const auto log = (dir / "check_interop.txt").string();
  const int rc = flat::test::run_program(args, log, 1200);
  const std::string report = flat::test::read_file(log);
  std::printf("%s (%s):\n%s", label.c_str(), require_all ? "--require-all" : "readers that are present",
              report.c_str());
  INFO(report);
  CHECK(rc == 0);
  CHECK(report.find("MISMATCH") == std::string::npos);
  return report;
}

}  // namespace

TEST_CASE("interop: trimesh, assimp and Blender read our PLY and GLB", "[.interop][export]") {
  const std::string python = interop_python();
  if (python.empty()) FLAT_SKIP("no python3: interop readers not run");
  if (!flat::exporter::glb_export_available()) REQUIRE_FALSE(interop_required());

  auto dir = flat::test::scratch_dir("interop");
  const int64_t n = 23;
  auto s = flat::test::random_soup(n, torch::kFloat, 21);
  s.colors[0] = torch::tensor({0.0f, 1.0f, 0.02f});  // ends of the range and the sRGB curve's linear toe
  const flat::primitives::TriangleSoup soup{s.vertices, s.colors, s.opacities, s.sigmas};
  const auto ply = (dir / "scene.ply").string();
  flat::exporter::write_triangle_ply(ply, soup);
  std::string glb = "-";
  if (flat::exporter::glb_export_available()) {
    glb = (dir / "scene.glb").string();
    flat::exporter::write_triangle_glb(glb, soup);
  }
  const std::string report = check_interop(python, {ply, glb, std::to_string(n)}, dir, "check_interop.py");
  if (report.find("UNAVAILABLE") != std::string::npos)
    WARN("some interop readers are unavailable (see above); CI sets FLAT_INTEROP_REQUIRE_ALL=1 to require them");
}

TEST_CASE("interop: trimesh, assimp and Blender read our opaque mesh GLB, PLY and OBJ", "[.interop][export]") {
  const std::string python = interop_python();
  if (python.empty()) FLAT_SKIP("no python3: interop readers not run");
  auto dir = flat::test::scratch_dir("interop_mesh");
  // 23 triangles whose corners are shared in a fan: vertices used by several faces.
  const auto s = flat::test::random_soup(23, torch::kFloat, 22);
  auto mesh = flat::primitives::mesh_from_soup({s.vertices, s.colors, s.opacities, s.sigmas});
  mesh.faces.select(1, 0).fill_(0);  // every face starts at vertex 0
  mesh = flat::primitives::compact_vertices(mesh);  // 1 + 2 x 23 vertices, none unused
  torch::manual_seed(5);  // fixed colours: the same check every run
  mesh.colors = torch::rand({mesh.num_vertices(), 3});
  mesh.colors[1] = torch::tensor({0.0f, 1.0f, 0.02f});
  const auto ply = (dir / "mesh.ply").string(), obj = (dir / "mesh.obj").string();
  flat::exporter::write_mesh_ply(ply, mesh);
  flat::exporter::write_mesh_obj(obj, mesh);
  std::string glb = "-";
  if (flat::exporter::glb_export_available()) {
    glb = (dir / "mesh.glb").string();
    flat::exporter::write_mesh_glb(glb, mesh);
  }
  const std::string report = check_interop(python, {"--mesh", glb, ply, obj}, dir, "check_interop.py --mesh");
  INFO(report);
  CHECK(report.find("reference PLY  47 vertices, 23 faces") != std::string::npos);
}

TEST_CASE("interop: check_interop.py started by a python without trimesh runs itself with the venv's",
          "[.interop][export]") {
  // A user runs the script with the system python, which lacks trimesh; the
  // project's venv (scripts/install_deps.sh) has it.
  const char* home = std::getenv("HOME");
  const std::string venv = home ? std::string(home) + "/.cache/flat/venv/bin/python3" : "";
  const std::string system = "/usr/bin/python3";
  auto dir = flat::test::scratch_dir("interop_python");
  const auto probe_log = (dir / "probe.txt").string();
  // Nothing to show where the system python has trimesh itself, or is absent.
  if (!std::filesystem::exists(system) || flat::test::run_program({system, "-c", "import trimesh"}, probe_log, 60) == 0)
    FLAT_SKIP("no system python without trimesh here");
  // The venv's trimesh is a reader CI requires.
  if (venv.empty() || !std::filesystem::exists(venv) ||
      flat::test::run_program({venv, "-c", "import trimesh"}, probe_log, 60) != 0) {
    REQUIRE_FALSE(interop_required());
    FLAT_SKIP("the project's venv has no trimesh (scripts/install_deps.sh)");
  }
  const auto s = flat::test::random_soup(5, torch::kFloat, 23);
  const auto ply = (dir / "scene.ply").string();
  flat::exporter::write_triangle_ply(ply, {s.vertices, s.colors, s.opacities, s.sigmas});
  const auto log = (dir / "check_interop.txt").string();
  const int rc = flat::test::run_program(
      {system, std::string(FLAT_SOURCE_DIR) + "/scripts/check_interop.py", ply, "-", "5"}, log, 600);
  const std::string report = flat::test::read_file(log);
  INFO(report);
  CHECK(rc == 0);
  CHECK(report.find("has no trimesh; running with " + venv) != std::string::npos);
  std::istringstream lines(report);
  int trimesh_lines = 0;
  for (std::string line; std::getline(lines, line);)
    if (line.find("trimesh") != std::string::npos && line.find("running with") == std::string::npos) {
      ++trimesh_lines;
      CHECK(line.find("UNAVAILABLE") == std::string::npos);
    }
  CHECK(trimesh_lines > 0);
}

TEST_CASE("interop: docs/inference.md's check_interop example runs as written on a flat_infer folder",
          "[.interop][export]") {
  // The example once hard-coded one model's triangle count (7,896), so a
  // reader who copied it got a MISMATCH for any other model. It must take the
  // count from the folder's summary.json, as written in the docs.
  const std::string docs = flat::test::read_file(std::string(FLAT_SOURCE_DIR) + "/docs/inference.md");
  const size_t at = docs.find("python3 scripts/check_interop.py runs/tiny/infer/room0/");
  REQUIRE(at != std::string::npos);
  std::string command;
  for (size_t pos = at;;) {  // the line and its backslash continuations
    const size_t end = docs.find('\n', pos);
    std::string line = docs.substr(pos, end - pos);
    const bool more = !line.empty() && line.back() == '\\';
    if (more) line.pop_back();
    command += line + " ";
    if (!more || end == std::string::npos) break;
    pos = end + 1;
  }
  INFO("the docs' command: " << command);
  CHECK(command.find("triangles_kept") != std::string::npos);
  CHECK(command.find("7896") == std::string::npos);

  // A flat_infer output folder at the docs' path with 13 triangles; the
  // command runs from a folder laid out like the repository (scripts/, runs/).
  auto root = flat::test::scratch_dir("interop_docs_example");
  std::filesystem::create_directory_symlink(std::string(FLAT_SOURCE_DIR) + "/scripts", root / "scripts");
  const auto out = root / "runs/tiny/infer/room0";
  std::filesystem::create_directories(out);
  const int64_t n = 13;
  auto s = flat::test::random_soup(n, torch::kFloat, 31);
  const flat::primitives::TriangleSoup soup{s.vertices, s.colors, s.opacities, s.sigmas};
  flat::exporter::write_triangle_ply((out / "scene.ply").string(), soup);
  if (!flat::exporter::glb_export_available()) {
    REQUIRE_FALSE(interop_required());
    FLAT_SKIP("built without GLB export");
  }
  flat::exporter::write_triangle_glb((out / "scene.glb").string(), soup);
  {
    std::ofstream summary(out / "summary.json");
    summary << "{\"triangles_decoded\": " << n << ", \"triangles_kept\": " << n << "}\n";
  }
  const auto log = (root / "example.txt").string();
  const int rc = flat::test::run_program(
      {"/bin/bash", "-c", "cd '" + root.string() + "' && " + command}, log, 900);
  const std::string report = flat::test::read_file(log);
  INFO(report);
  if (rc != 0 && !interop_required() && report.find("UNAVAILABLE") != std::string::npos)
    FLAT_SKIP("a reader is missing here (--require-all); CI has them all");
  CHECK(rc == 0);
  CHECK(report.find("MISMATCH") == std::string::npos);
}
