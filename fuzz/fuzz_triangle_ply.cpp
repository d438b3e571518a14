// libFuzzer target: arbitrary bytes as a triangle PLY. The contract under
// test: parse_triangle_ply either returns triangles whose arrays match the
// face count, or throws flat::Error (any other exception, a crash, a
// sanitizer report or an allocation beyond -rss_limit_mb is a bug: header
// counts are checked against the bytes that follow before allocating).
#include <cstddef>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <sstream>
#include <string>

#include "flat/core/error.h"
#include "flat/export/triangle_ply_parse.h"

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  std::istringstream in(std::string(reinterpret_cast<const char*>(data), size), std::ios::binary);
  flat::exporter::PlyTriangles t;
  try {
    t = flat::exporter::parse_triangle_ply(in, "fuzz.ply");
  } catch (const flat::Error&) {
    return 0;  // rejected with a message
  }
  const size_t n = size_t(t.faces);
  if (t.vertices.size() != 9 * n || t.colors.size() != 3 * n || t.opacities.size() != n || t.sigmas.size() != n) {
    std::fprintf(stderr, "array sizes do not match %zu faces\n", n);
    std::abort();
  }
  // Every face takes 33 bytes of the input: more faces than that is a parser bug.
  if (n * 33 > size) {
    std::fprintf(stderr, "%zu faces from %zu bytes\n", n, size);
    std::abort();
  }
  return 0;
}
