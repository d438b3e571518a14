// The offline viewer folder: our page, three.js's files, the GLB as base64
// in a script (file:// pages may load scripts but not fetch files).
#include "flat/export/viewer.h"

#include <fcntl.h>
#include <unistd.h>

#include <cerrno>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <fstream>

#include <nlohmann/json.hpp>

#include "flat/core/atomic_file.h"
#include "flat/core/error.h"
#include "viewer_page.h"

namespace flat::exporter {
namespace {

namespace fs = std::filesystem;

// (file in the three.js folder, name in the viewer folder)
constexpr const char* kThreeFiles[][2] = {
    {"three.min.js", "three.min.js"},
    {"examples/js/controls/OrbitControls.js", "OrbitControls.js"},
    {"examples/js/loaders/GLTFLoader.js", "GLTFLoader.js"},
};

std::string read_bytes(const std::string& path, const std::string& what) {
  std::ifstream in(path, std::ios::binary);
  FLAT_CHECK(in.good(), path + ": cannot open " + what);
  std::string bytes((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
  FLAT_CHECK(!in.bad(), path + ": cannot read " + what);
  return bytes;
}

std::string base64(const std::string& bytes) {
  static const char* abc = "ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789+/";
  std::string out;
  out.reserve((bytes.size() + 2) / 3 * 4);
  size_t i = 0;
  for (; i + 2 < bytes.size(); i += 3) {
    const uint32_t v = uint32_t(uint8_t(bytes[i])) << 16 | uint32_t(uint8_t(bytes[i + 1])) << 8 | uint8_t(bytes[i + 2]);
    for (int s = 18; s >= 0; s -= 6) out += abc[(v >> s) & 63];
  }
  if (i < bytes.size()) {  // 1 or 2 bytes left: pad with '='
    const bool two = i + 1 < bytes.size();
    const uint32_t v = uint32_t(uint8_t(bytes[i])) << 16 | (two ? uint32_t(uint8_t(bytes[i + 1])) << 8 : 0u);
    out += abc[(v >> 18) & 63];
    out += abc[(v >> 12) & 63];
    out += two ? abc[(v >> 6) & 63] : '=';
    out += '=';
  }
  return out;
}

// Replacing a folder is only safe when it is ours (or empty): never delete a
// user's folder because it was named as the output by mistake.
void check_replaceable(const std::string& folder) {
  std::error_code ec;
  if (!fs::exists(folder, ec)) return;
  FLAT_CHECK(fs::is_directory(folder, ec), folder + ": exists and is not a folder; not replaced by the viewer");
  if (fs::is_empty(folder, ec)) return;
  const std::string index = (fs::path(folder) / "index.html").string();
  std::ifstream in(index);
  std::string head(512, '\0');
  in.read(&head[0], std::streamsize(head.size()));
  head.resize(size_t(in.gcount()));
  FLAT_CHECK(head.find(kViewerMarker) != std::string::npos,
             folder + ": exists and is not a FLAT viewer folder (no index.html of ours); not replaced");
}

// The folder is built beside its target and swapped in whole, so that a page
// never mixes an old scene with new files.
class StagingFolder {
 public:
  explicit StagingFolder(const std::string& target)
      : target_(target), path_(target + ".incomplete-" + std::to_string(::getpid())) {
    std::error_code ec;
    fs::remove_all(path_, ec);
    fs::create_directories(path_, ec);
    FLAT_CHECK(!ec, target_ + ": cannot create the staging folder " + path_ + ": " + ec.message());
  }
  ~StagingFolder() {
    std::error_code ec;
    if (!committed_) fs::remove_all(path_, ec);
  }
  std::string file(const std::string& name) const { return path_ + "/" + name; }
  void commit() {
    std::error_code ec;
    if (fs::exists(target_, ec)) {
      // Atomic exchange where the file system has it, else old aside, new in.
      if (::renameat2(AT_FDCWD, path_.c_str(), AT_FDCWD, target_.c_str(), RENAME_EXCHANGE) != 0) {
        const std::string old = target_ + ".old-" + std::to_string(::getpid());
        FLAT_CHECK(std::rename(target_.c_str(), old.c_str()) == 0,
                   target_ + ": cannot move the old viewer aside: " + std::strerror(errno));
        if (std::rename(path_.c_str(), target_.c_str()) != 0) {
          const std::string why = std::strerror(errno);
          std::rename(old.c_str(), target_.c_str());
          fail(target_ + ": cannot move the new viewer into place: " + why);
        }
        fs::remove_all(old, ec);
      } else {
        fs::remove_all(path_, ec);  // now holds the old folder
      }
    } else {
      FLAT_CHECK(std::rename(path_.c_str(), target_.c_str()) == 0,
                 target_ + ": cannot move the viewer into place: " + std::strerror(errno));
    }
    committed_ = true;
  }

 private:
  std::string target_, path_;
  bool committed_ = false;
};

}  // namespace

std::string default_three_js_dir() { return "/usr/share/javascript/three"; }

bool viewer_available(const std::string& three_dir) {
  std::error_code ec;
  for (const auto& f : kThreeFiles)
    if (!fs::is_regular_file(fs::path(three_dir) / f[0], ec)) return false;
  return true;
}

void write_viewer(const std::string& folder, const std::string& glb_path, const camera::CameraSet& start,
                  const std::string& three_dir, const std::string& mesh_glb_path) {
  FLAT_CHECK(viewer_available(three_dir),
             folder + ": cannot write the viewer: three.js r111 not found in '" + three_dir +
                 "' (Debian package libjs-three; needs three.min.js, examples/js/controls/OrbitControls.js and "
                 "examples/js/loaders/GLTFLoader.js)");
  const std::string glb = read_bytes(glb_path, "GLB for the viewer");
  FLAT_CHECK(glb.size() >= 12 && glb.compare(0, 4, "glTF") == 0, glb_path + ": not a GLB file (no 'glTF' magic)");
  std::string mesh_glb;
  if (!mesh_glb_path.empty()) {
    mesh_glb = read_bytes(mesh_glb_path, "mesh GLB for the viewer");
    FLAT_CHECK(mesh_glb.size() >= 12 && mesh_glb.compare(0, 4, "glTF") == 0,
               mesh_glb_path + ": not a GLB file (no 'glTF' magic)");
  }
  nlohmann::json cams = {{"version", 1}, {"cameras", nlohmann::json::array()}};
  if (start.cameras.intrinsics.defined()) start.cameras.check(folder + ": viewer start cameras");
  if (start.cameras.intrinsics.defined() && start.cameras.size() > 0) {
    FLAT_CHECK(start.width > 0 && start.height > 0, folder + ": viewer start cameras need a positive width and height");
    for (int64_t i = 0; i < start.cameras.size(); ++i)
      cams["cameras"].push_back(
          camera::camera_entry(start.cameras.intrinsics[i], start.cameras.c2w[i], start.width, start.height));
  }
  std::string target = folder;
  while (target.size() > 1 && target.back() == '/') target.pop_back();
  FLAT_CHECK(!target.empty(), "viewer: empty output folder");
  check_replaceable(target);
  const fs::path parent = fs::path(target).parent_path();
  std::error_code ec;
  if (!parent.empty()) fs::create_directories(parent, ec);
  FLAT_CHECK(!ec, target + ": cannot create its parent folder: " + ec.message());

  StagingFolder dir(target);
  for (const auto& f : kThreeFiles)
    write_file_atomic(dir.file(f[1]), read_bytes((fs::path(three_dir) / f[0]).string(), "three.js file"));
  write_file_atomic(dir.file("scene_glb.js"), "// " + fs::path(glb_path).filename().string() +
                                                   ", base64 (FLAT-C++ viewer)\nwindow.FLAT_SCENE_GLB = \"" +
                                                   base64(glb) + "\";\n");
  // Always written (empty without a mesh), so that the page's script tag never 404s.
  write_file_atomic(dir.file("mesh_glb.js"),
                    mesh_glb.empty() ? std::string("// no opaque mesh (FLAT-C++ viewer)\n")
                                     : "// " + fs::path(mesh_glb_path).filename().string() +
                                           ", base64 (FLAT-C++ viewer)\nwindow.FLAT_MESH_GLB = \"" + base64(mesh_glb) +
                                           "\";\n");
  write_file_atomic(dir.file("cameras.js"), "// Start cameras (docs/formats.md, cameras JSON)\nwindow.FLAT_CAMERAS = " +
                                                 cams.dump() + ";\n");
  write_file_atomic(dir.file("index.html"), std::string(viewer_index_html()));
  dir.commit();
}

std::string write_viewer_if_available(const std::string& folder, const std::string& glb_path,
                                      const camera::CameraSet& start_cameras, const std::string& three_dir,
                                      const std::string& mesh_glb_path) {
  const std::string three = three_dir.empty() ? default_three_js_dir() : three_dir;
  if (!viewer_available(three))
    return "viewer not written: three.js not found in " + three + " (Debian package libjs-three)";
  write_viewer(folder, glb_path, start_cameras, three, mesh_glb_path);
  return "";
}

}  // namespace flat::exporter
