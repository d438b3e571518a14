// libFuzzer target: arbitrary bytes as a cameras JSON (docs/formats.md). The
// contract under test: parse_cameras_document either returns cameras that
// satisfy the format's rules (one image size, positive focal lengths, finite
// values, an orthonormal rotation) or throws flat::Error; any other exception,
// a crash or a sanitizer report is a bug.
#include <cmath>
#include <cstddef>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <string>

#include "flat/camera/camera_records.h"
#include "flat/core/error.h"

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  const std::string text(reinterpret_cast<const char*>(data), size);
  std::vector<flat::camera::CameraRecord> cams;
  try {
    cams = flat::camera::parse_cameras_document(text, "fuzz.json");
  } catch (const flat::Error&) {
    return 0;  // rejected with a message
  }
  const auto bad = [](const char* what) {
    std::fprintf(stderr, "accepted a camera with %s\n", what);
    std::abort();
  };
  if (cams.empty()) bad("no entries");
  for (const auto& c : cams) {
    if (c.width != cams[0].width || c.height != cams[0].height) bad("mixed sizes");
    if (c.width <= 0 || c.height <= 0) bad("a non-positive size");
    if (!(c.intrinsics[0] > 0) || !(c.intrinsics[1] > 0)) bad("a non-positive focal length");
    for (float x : c.intrinsics)
      if (!std::isfinite(x)) bad("a non-finite intrinsic");
    for (float x : c.c2w)
      if (!std::isfinite(x)) bad("a non-finite pose");
  }
  return 0;
}
