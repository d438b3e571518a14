// Writes the seed corpus of fuzz_safetensors with the project's own writer:
// small valid files covering every dtype, zero-size tensors, scalars and
// metadata. The fuzzer mutates these into malformed ones.
//   make_safetensors_corpus <folder>
#include <cstdint>
#include <cstdio>
#include <string>
#include <vector>

#include "flat/core/error.h"
#include "flat/core/safetensors.h"

namespace st = flat::safetensors;

int main(int argc, char** argv) {
  if (argc != 2) {
    std::fprintf(stderr, "usage: %s <corpus folder>\n", argv[0]);
    return 2;
  }
  const std::string dir = argv[1];
  std::vector<uint8_t> bytes(64);
  for (size_t i = 0; i < bytes.size(); ++i) bytes[i] = static_cast<uint8_t>(i * 37 + 11);
  try {
    st::write(dir + "/empty.safetensors", {});
    st::write(dir + "/one_f32.safetensors", {{"weight", st::DType::F32, {2, 3}, bytes.data(), 24}});
    st::write(dir + "/scalar_meta.safetensors", {{"step", st::DType::I64, {}, bytes.data(), 8}},
              {{"format", "pt"}, {"stage", "1"}});
    // Every dtype once, plus zero-size tensors between them.
    std::vector<st::RawTensor> all;
    const char* names[] = {"BOOL", "U8", "I8", "I16", "U16", "I32", "U32", "I64",
                           "U64", "F16", "BF16", "F32", "F64", "F8_E4M3", "F8_E5M2"};
    for (const char* name : names) {
      auto dtype = *st::parse_dtype(name);
      all.push_back({std::string("t_") + name, dtype, {2}, bytes.data(), 2 * st::dtype_size(dtype)});
    }
    all.push_back({"empty_a", st::DType::F32, {0, 4}, nullptr, 0});
    all.push_back({"empty_b", st::DType::BF16, {3, 0}, nullptr, 0});
    st::write(dir + "/all_dtypes.safetensors", all, {{"note", "seed"}});
  } catch (const flat::Error& e) {
    std::fprintf(stderr, "error: %s\n", e.what());
    return 1;
  }
  return 0;
}
