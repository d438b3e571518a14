// libFuzzer target: flat::safetensors::parse on arbitrary bytes. A malformed
// file may only produce flat::Error; anything else (a crash, a sanitizer
// report, another exception type) is a bug. When parsing succeeds, the header
// must describe ranges that tile the data buffer, which is checked here so
// that a parser accepting a bad file is caught too.
#include <cstddef>
#include <cstdint>
#include <cstdlib>

#include "flat/core/error.h"
#include "flat/core/safetensors.h"

namespace st = flat::safetensors;

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  st::Header header;
  try {
    header = st::parse(data, size, "fuzz");
  } catch (const flat::Error&) {
    return 0;  // rejected cleanly
  }
  if (header.data_start < 8 || header.data_start > size) std::abort();
  const uint64_t buffer = size - header.data_start;
  uint64_t cursor = 0;
  for (const auto& e : header.entries) {
    if (e.begin != cursor || e.end < e.begin || e.end > buffer) std::abort();
    if (e.end - e.begin != e.numel() * st::dtype_size(e.dtype)) std::abort();
    if (header.find(e.name) != &e) std::abort();  // names are unique and indexed
    cursor = e.end;
  }
  if (cursor != buffer) std::abort();
  return 0;
}
