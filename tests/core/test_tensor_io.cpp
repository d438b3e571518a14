// safetensors <-> at::Tensor: bit-exact round trips for every dtype, atomic
// replacement, and the shape-checked loader's messages.
#include <cstring>
#include <filesystem>
#include <fstream>

#include "flat/core/error.h"
#include "flat/core/tensor_io.h"
#include "support/read_file.h"
#include "test_support.h"

namespace {

namespace fs = std::filesystem;
using flat::test::read_file;

// Random bit patterns (NaNs and infinities included for the float types),
// except BOOL, which only holds 0 or 1.
at::Tensor random_tensor(at::ScalarType type, std::vector<int64_t> shape, at::Generator& gen) {
  auto t = at::empty(shape, at::TensorOptions().dtype(type));
  if (type == at::kBool) return at::randint(0, 2, shape, gen, at::kLong).to(at::kBool);
  auto bytes = at::randint(0, 256, {t.nbytes() ? static_cast<int64_t>(t.nbytes()) : 0}, gen, at::kLong).to(at::kByte);
  if (t.nbytes() > 0) std::memcpy(t.data_ptr(), bytes.data_ptr(), t.nbytes());
  return t;
}

bool same_bits(const at::Tensor& a, const at::Tensor& b) {
  return a.scalar_type() == b.scalar_type() && a.sizes() == b.sizes() && a.is_contiguous() && b.is_contiguous() &&
         std::memcmp(a.data_ptr(), b.data_ptr(), a.nbytes()) == 0;
}

std::vector<std::string> temp_files(const fs::path& dir) {
  std::vector<std::string> out;
  for (const auto& item : fs::directory_iterator(dir)) {
    if (item.path().filename().string().find(".tmp.") != std::string::npos) out.push_back(item.path().string());
  }
  return out;
}

}  // namespace

TEST_CASE("every dtype round-trips bit-exactly, with metadata and a zero-size tensor", "[core][tensor_io]") {
  const std::vector<std::pair<at::ScalarType, const char*>> types = {
      {at::kBool, "BOOL"},        {at::kByte, "U8"},          {at::kChar, "I8"},          {at::kShort, "I16"},
      {at::kUInt16, "U16"},       {at::kInt, "I32"},          {at::kUInt32, "U32"},       {at::kLong, "I64"},
      {at::kUInt64, "U64"},       {at::kHalf, "F16"},         {at::kBFloat16, "BF16"},    {at::kFloat, "F32"},
      {at::kDouble, "F64"},       {at::kFloat8_e4m3fn, "F8_E4M3"}, {at::kFloat8_e5m2, "F8_E5M2"}};
  REQUIRE(types.size() == 15);
  auto gen = at::make_generator<at::CPUGeneratorImpl>(42);
  flat::TensorMap tensors;
  for (size_t i = 0; i < types.size(); ++i) {
    tensors[std::string("t_") + types[i].second] = random_tensor(types[i].first, {2, 3, static_cast<int64_t>(i + 1)}, gen);
  }
  tensors["zero_size"] = at::empty({4, 0, 2}, at::kFloat);
  tensors["scalar"] = at::full({}, 2.5, at::kDouble);
  const flat::Metadata metadata = {{"format", "pt"}, {"stage", "1"}};

  auto dir = flat::test::scratch_dir("tensor_io_roundtrip");
  const std::string path = (dir / "all.safetensors").string();
  flat::save_safetensors(path, tensors, metadata);

  flat::Metadata loaded_meta;
  auto loaded = flat::load_safetensors(path, &loaded_meta);
  CHECK(loaded_meta == metadata);
  REQUIRE(loaded.size() == tensors.size());
  for (const auto& [name, t] : tensors) {
    INFO("tensor " << name);
    REQUIRE(loaded.count(name) == 1);
    CHECK(same_bits(loaded.at(name), t));
  }
  CHECK(loaded.at("zero_size").sizes() == at::IntArrayRef({4, 0, 2}));
  CHECK(loaded.at("scalar").dim() == 0);

  // The header spells the format's dtype names.
  auto file = flat::safetensors::MappedFile::open(path);
  for (const auto& [type, name] : types) {
    CHECK(flat::safetensors::dtype_name(file->at(std::string("t_") + name).dtype) == name);
  }
  // Loaded tensors own their memory: they outlive the mapping.
  auto single = flat::read_tensor(*file, "t_F32");
  file.reset();
  CHECK(same_bits(single, tensors.at("t_F32")));
}

TEST_CASE("saving makes views contiguous and rejects what safetensors cannot hold", "[core][tensor_io]") {
  auto dir = flat::test::scratch_dir("tensor_io_views");
  const std::string path = (dir / "v.safetensors").string();
  auto base = at::arange(12, at::kFloat).view({3, 4});
  flat::save_safetensors(path, {{"t", base.t()}, {"slice", base.index({at::indexing::Slice(), 1})}});
  auto loaded = flat::load_safetensors(path);
  CHECK(at::equal(loaded.at("t"), base.t()));
  CHECK(at::equal(loaded.at("slice"), at::tensor({1.f, 5.f, 9.f})));

  REQUIRE_THROWS_WITH(flat::save_safetensors(path, {{"c", at::zeros({2}, at::kComplexFloat)}}),
                      FLAT_CONTAINS("tensor \"c\"") && FLAT_CONTAINS("no safetensors equivalent"));
  REQUIRE_THROWS_WITH(flat::save_safetensors(path, {{"u", at::Tensor()}}), FLAT_CONTAINS("\"u\": undefined tensor"));
}

TEST_CASE("a failing write leaves the existing file untouched and no temp files", "[core][tensor_io]") {
  auto dir = flat::test::scratch_dir("tensor_io_atomic");
  const std::string path = (dir / "weights.safetensors").string();
  flat::save_safetensors(path, {{"w", at::arange(6, at::kFloat)}});
  const std::string good = read_file(path);

  // Duplicate names: rejected before anything is written.
  const float x[2] = {1.f, 2.f};
  REQUIRE_THROWS_WITH(flat::safetensors::write(path, {{"a", flat::safetensors::DType::F32, {2}, x, sizeof x},
                                                      {"a", flat::safetensors::DType::F32, {2}, x, sizeof x}}),
                      FLAT_CONTAINS("duplicate"));
  // An unsupported dtype after a good tensor: also rejected before writing.
  REQUIRE_THROWS(flat::save_safetensors(path, {{"a", at::ones({3})}, {"b", at::ones({2}, at::kComplexDouble)}}));

  CHECK(read_file(path) == good);
  CHECK(temp_files(dir).empty());
  CHECK(at::equal(flat::load_safetensors(path).at("w"), at::arange(6, at::kFloat)));

  // A successful write replaces it and leaves no temp file either.
  flat::save_safetensors(path, {{"w2", at::ones({2})}});
  CHECK(flat::load_safetensors(path).count("w2") == 1);
  CHECK(temp_files(dir).empty());
}

TEST_CASE("load_tensor_checked names file, tensor, layout and actual shape", "[core][tensor_io]") {
  auto dir = flat::test::scratch_dir("tensor_io_checked");
  const std::string path = (dir / "latent.safetensors").string();
  flat::save_safetensors(path, {{"z", at::zeros({1, 16, 2, 4, 6})}});

  auto z = flat::load_tensor_checked(path, "z", {-1, 16, -1, -1, -1}, "(B,16,T,h,w)");
  CHECK(z.sizes() == at::IntArrayRef({1, 16, 2, 4, 6}));

  REQUIRE_THROWS_WITH(flat::load_tensor_checked(path, "z", {-1, 8, -1, -1, -1}, "(B,8,T,h,w)"),
                      FLAT_CONTAINS(path) && FLAT_CONTAINS("tensor \"z\"") && FLAT_CONTAINS("(B,8,T,h,w)") &&
                          FLAT_CONTAINS("(1,16,2,4,6)"));
  REQUIRE_THROWS_WITH(flat::load_tensor_checked(path, "z", {-1, 16, -1, -1}, "(B,16,h,w)"),
                      FLAT_CONTAINS("expected shape (B,16,h,w)") && FLAT_CONTAINS("got (1,16,2,4,6)"));
  REQUIRE_THROWS_WITH(flat::load_tensor_checked(path, "latent", {-1}, "(N)"),
                      FLAT_CONTAINS(path) && FLAT_CONTAINS("no tensor \"latent\"") && FLAT_CONTAINS("z"));
  const std::string missing = (dir / "nope.safetensors").string();
  REQUIRE_THROWS_WITH(flat::load_tensor_checked(missing, "z", {-1}, "(N)"), FLAT_CONTAINS(missing));
}
