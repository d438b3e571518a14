// A self-contained offline viewer folder for a GLB written by
// write_triangle_glb: open index.html from disk in any browser (no server).
//   index.html        our page (src/export/viewer_page.cpp)
//   three.min.js, OrbitControls.js, GLTFLoader.js   copied from three.js r111
//   scene_glb.js      the GLB, base64 (browsers refuse XHR/fetch of file://)
//   mesh_glb.js       the opaque mesh GLB (mesh_files.h), base64, when given:
//                     the page then has a soup / mesh toggle (button, key M)
//   cameras.js        the start cameras, as in the cameras JSON (docs/formats.md)
// URL parameters (docs/formats.md, "Viewer"): camera=K (start camera K), or
// c2w=<16 numbers, row-major OpenCV camera-to-world>&fx=..&fy=..&cx=..&cy=..
// (intrinsics normalised by the image size, as in camera_json.h); bg=RRGGBB;
// show=mesh (start on the opaque mesh).
// The projection comes from the intrinsics (off-centre principal points
// included), so a W x H window shows what rasterize() renders at W x H.
#pragma once
#include <string>

#include "flat/camera/camera_json.h"

namespace flat::exporter {

std::string default_three_js_dir();  // /usr/share/javascript/three (Debian libjs-three)

// True when three_dir holds three.min.js, examples/js/controls/OrbitControls.js
// and examples/js/loaders/GLTFLoader.js.
bool viewer_available(const std::string& three_dir);

// Builds the folder in a staging folder beside it and renames it into place. An
// existing folder is replaced only when it is empty or a viewer we wrote
// (otherwise flat::Error). start_cameras may be empty (the view then frames
// the scene).
void write_viewer(const std::string& folder, const std::string& glb_path, const camera::CameraSet& start_cameras,
                  const std::string& three_dir, const std::string& mesh_glb_path = "");

// For the tools (flat_infer, flat_mesh), where a missing three.js is a note,
// not an error: write_viewer() with three_dir (empty: default_three_js_dir())
// when it holds three.js. Returns "" once written, else why it was not.
std::string write_viewer_if_available(const std::string& folder, const std::string& glb_path,
                                      const camera::CameraSet& start_cameras, const std::string& three_dir,
                                      const std::string& mesh_glb_path = "");

}  // namespace flat::exporter
