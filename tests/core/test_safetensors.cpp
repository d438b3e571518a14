// The torch-free safetensors layer: malformed files (one row per defect, each
// with the specific message it must produce), valid corner cases, the writer's
// layout, and opening files that are missing, empty or folders.
#include <unistd.h>

#include <cstring>
#include <filesystem>
#include <fstream>

#include "flat/core/error.h"
#include "flat/core/safetensors.h"
#include "support/read_file.h"
#include "test_support.h"

namespace st = flat::safetensors;
using flat::test::read_file;

namespace {

// 8-byte little-endian header length + header text + `buffer` zero bytes.
std::string file_bytes(const std::string& header, size_t buffer = 0) {
  std::string out(8, '\0');
  uint64_t n = header.size();
  for (int i = 0; i < 8; ++i) out[i] = static_cast<char>((n >> (8 * i)) & 0xff);
  return out + header + std::string(buffer, '\0');
}

// Just a length prefix (for lengths that do not match the content).
std::string length_prefix(uint64_t n) {
  std::string out(8, '\0');
  for (int i = 0; i < 8; ++i) out[i] = static_cast<char>((n >> (8 * i)) & 0xff);
  return out;
}

st::Header parse_bytes(const std::string& bytes, const std::string& label = "test.safetensors") {
  return st::parse(reinterpret_cast<const uint8_t*>(bytes.data()), bytes.size(), label);
}

std::string error_of(const std::string& bytes) {
  try {
    parse_bytes(bytes);
  } catch (const flat::Error& e) {
    return e.what();
  }
  return "<no error>";
}

struct Malformed {
  const char* defect;
  std::string bytes;
  const char* message;  // the specific part of the error
  const char* tensor;   // the tensor the message must name ("" if none)
};

}  // namespace

TEST_CASE("malformed safetensors files are rejected with specific messages", "[core][safetensors]") {
  const std::string f32x2 = R"("dtype":"F32","shape":[2])";
  const std::vector<Malformed> rows = {
      {"shorter than the length prefix", std::string("\x01\x02\x03\x04\x05", 5), "truncated file: 5 bytes", ""},
      {"header length past the end", length_prefix(64) + "{}", "truncated file: header length 64 runs past", ""},
      {"header over 100 MB", length_prefix(100'000'001) + "{}", "exceeds the 100 MB limit", ""},
      // torch.save's zip (what Wan's official .pth is) and its older pickle: named, with what to do.
      {"a torch.save zip (.pth)", std::string("PK\x03\x04\x14\x00\x00\x00", 8) + "archive/data.pkl", "a PyTorch checkpoint",
       ""},
      {"a legacy torch.save pickle", std::string("\x80\x02\x8a\x0a" "l" "\xfc\x9c" "F", 8) + "....", "docs/model.md", ""},
      {"huge header length (no overflow)", length_prefix(~0ull), "exceeds the 100 MB limit", ""},
      {"invalid JSON", file_bytes(R"({"a": )"), "header is not valid JSON", ""},
      {"invalid UTF-8 in a name", file_bytes("{\"\xff\xfe\": {}}"), "header is not valid JSON", ""},
      {"deeply nested JSON", file_bytes(std::string(100000, '[') + std::string(100000, ']')),
       "nests deeper than 64 levels", ""},
      {"JSON array instead of object", file_bytes("[1, 2]"), "header JSON must be an object, got array", ""},
      {"entry not an object", file_bytes(R"({"w": 5})"), "entry must be an object, got number", "w"},
      {"missing dtype", file_bytes(R"({"w": {"shape":[1],"data_offsets":[0,4]}})", 4), "missing \"dtype\"", "w"},
      {"dtype not a string", file_bytes(R"({"w": {"dtype":4,"shape":[1],"data_offsets":[0,4]}})", 4),
       "\"dtype\" must be a string", "w"},
      {"unknown dtype", file_bytes(R"({"w": {"dtype":"F128","shape":[1],"data_offsets":[0,16]}})", 16),
       "unknown dtype \"F128\"", "w"},
      {"missing shape", file_bytes(R"({"w": {"dtype":"F32","data_offsets":[0,4]}})", 4), "missing \"shape\"", "w"},
      {"shape not an array", file_bytes(R"({"w": {"dtype":"F32","shape":4,"data_offsets":[0,16]}})", 16),
       "\"shape\" must be an array", "w"},
      {"negative dimension", file_bytes(R"({"w": {"dtype":"F32","shape":[-2],"data_offsets":[0,0]}})"),
       "negative dimension -2", "w"},
      {"non-integer dimension", file_bytes(R"({"w": {"dtype":"F32","shape":[2.5],"data_offsets":[0,8]}})", 8),
       "must hold non-negative integers, got 2.5", "w"},
      {"dimension beyond int64",
       file_bytes(R"({"w": {"dtype":"U8","shape":[9223372036854775808],"data_offsets":[0,0]}})"), "overflows int64",
       "w"},
      {"shape product overflow",
       file_bytes(R"({"w": {"dtype":"F32","shape":[4294967296,4294967296,4],"data_offsets":[0,0]}})"),
       "overflows (element count too large)", "w"},
      {"missing data_offsets", file_bytes(R"({"w": {"dtype":"F32","shape":[1]}})", 4), "missing \"data_offsets\"", "w"},
      {"data_offsets with one number", file_bytes(R"({"w": {"dtype":"F32","shape":[1],"data_offsets":[4]}})", 4),
       "\"data_offsets\" must be [begin, end]", "w"},
      {"negative data offset", file_bytes(R"({"w": {"dtype":"F32","shape":[1],"data_offsets":[-4,0]}})", 4),
       "\"data_offsets\" must be [begin, end]", "w"},
      {"begin after end", file_bytes(R"({"w": {"dtype":"F32","shape":[1],"data_offsets":[8,4]}})", 8),
       "have begin > end", "w"},
      {"offsets out of range", file_bytes(R"({"w": {"dtype":"F32","shape":[4],"data_offsets":[0,16]}})", 8),
       "out of range of the 8-byte data buffer", "w"},
      {"size != numel * itemsize", file_bytes(R"({"w": {"dtype":"F32","shape":[3],"data_offsets":[0,8]}})", 8),
       "size mismatch", "w"},
      {"overlapping ranges",
       file_bytes(R"({"a": {)" + f32x2 + R"(,"data_offsets":[0,8]}, "b": {)" + f32x2 + R"(,"data_offsets":[4,12]}})", 12),
       "overlap", "b"},
      {"gap between ranges",
       file_bytes(R"({"a": {)" + f32x2 + R"(,"data_offsets":[0,8]}, "b": {)" + f32x2 + R"(,"data_offsets":[12,20]}})", 20),
       "gap in the data buffer: bytes [8, 12) before tensor \"b\"", "b"},
      {"gap before the first range", file_bytes(R"({"a": {)" + f32x2 + R"(,"data_offsets":[4,12]}})", 12),
       "gap in the data buffer: bytes [0, 4)", "a"},
      {"trailing bytes after the last tensor", file_bytes(R"({"a": {)" + f32x2 + R"(,"data_offsets":[0,8]}})", 12),
       "4 trailing bytes after the last tensor", "a"},
      {"bytes but no tensors", file_bytes("{}", 4), "4 trailing bytes after the last tensor (buffer [0, 4) unused)", ""},
      {"duplicate tensor names",
       file_bytes(R"({"a": {)" + f32x2 + R"(,"data_offsets":[0,8]}, "a": {)" + f32x2 + R"(,"data_offsets":[8,16]}})", 16),
       "duplicate key \"a\"", "a"},
      {"duplicate key inside an entry",
       file_bytes(R"({"a": {"dtype":"F32","dtype":"U8","shape":[2],"data_offsets":[0,8]}})", 8), "duplicate key \"dtype\" inside \"a\"",
       "a"},
      {"metadata not an object", file_bytes(R"({"__metadata__": [1]})"), "__metadata__ must be an object", ""},
      {"metadata value not a string", file_bytes(R"({"__metadata__": {"epoch": 3}})"),
       "__metadata__ key \"epoch\" must map to a string", ""},
  };
  REQUIRE(rows.size() >= 14);
  for (const auto& row : rows) {
    INFO("defect: " << row.defect);
    const std::string message = error_of(row.bytes);
    CHECK_THAT(message, FLAT_CONTAINS(row.message));
    CHECK_THAT(message, FLAT_CONTAINS("test.safetensors: "));  // the label comes first
    if (*row.tensor) CHECK_THAT(message, FLAT_CONTAINS(std::string("\"") + row.tensor + "\""));
  }
}

TEST_CASE("valid corner cases parse", "[core][safetensors]") {
  SECTION("no tensors at all") {
    auto h = parse_bytes(file_bytes("{}"));
    CHECK(h.entries.empty());
    CHECK(h.data_start == 10);
  }
  SECTION("zero-size tensors anywhere, header padded with spaces") {
    auto h = parse_bytes(file_bytes(R"({"e": {"dtype":"F32","shape":[0,3],"data_offsets":[4,4]},)"
                                    R"( "b": {"dtype":"I32","shape":[1],"data_offsets":[0,4]},)"
                                    R"( "c": {"dtype":"U8","shape":[2,2],"data_offsets":[4,8]},)"
                                    R"( "z": {"dtype":"BOOL","shape":[0],"data_offsets":[8,8]}}   )",
                                    8));
    REQUIRE(h.entries.size() == 4);
    // entries come in data-offset order
    CHECK(h.entries[0].name == "b");
    CHECK(h.entries[1].name == "e");
    CHECK(h.entries[2].name == "c");
    CHECK(h.entries[3].name == "z");
    REQUIRE(h.find("e") != nullptr);
    CHECK(h.find("e")->numel() == 0);
    CHECK(h.find("e")->shape == std::vector<int64_t>{0, 3});
    CHECK(h.find("missing") == nullptr);
  }
  SECTION("scalar (empty shape) and metadata") {
    auto h = parse_bytes(file_bytes(
        R"({"__metadata__": {"format": "pt", "step": "7"}, "s": {"dtype":"F64","shape":[],"data_offsets":[0,8]}})", 8));
    REQUIRE(h.entries.size() == 1);
    CHECK(h.entries[0].numel() == 1);
    CHECK(h.metadata.at("format") == "pt");
    CHECK(h.metadata.at("step") == "7");
  }
}

TEST_CASE("dtype names and sizes", "[core][safetensors]") {
  const std::vector<std::pair<const char*, size_t>> expected = {
      {"BOOL", 1}, {"U8", 1},   {"I8", 1},   {"I16", 2}, {"U16", 2},     {"I32", 4},     {"U32", 4}, {"I64", 8},
      {"U64", 8},  {"F16", 2},  {"BF16", 2}, {"F32", 4}, {"F64", 8}, {"F8_E4M3", 1}, {"F8_E5M2", 1}};
  for (const auto& [name, size] : expected) {
    auto d = st::parse_dtype(name);
    REQUIRE(d.has_value());
    CHECK(st::dtype_name(*d) == name);
    CHECK(st::dtype_size(*d) == size);
  }
  CHECK(!st::parse_dtype("f32").has_value());
  CHECK(!st::parse_dtype("").has_value());
}

TEST_CASE("writer lays tensors out in the given order with a padded header", "[core][safetensors]") {
  auto dir = flat::test::scratch_dir("safetensors_writer");
  const std::string path = (dir / "out.safetensors").string();
  const float b[3] = {1.f, 2.f, 3.f};
  const int16_t a[2] = {-7, 9};
  st::write(path, {{"b", st::DType::F32, {3}, b, sizeof b}, {"a", st::DType::I16, {2, 1}, a, sizeof a},
                   {"empty", st::DType::F16, {0, 5}, nullptr, 0}},
            {{"note", "hello"}});

  const std::string bytes = read_file(path);
  uint64_t n = 0;
  std::memcpy(&n, bytes.data(), 8);
  CHECK(n % 8 == 0);
  CHECK(bytes.size() == 8 + n + sizeof b + sizeof a);
  CHECK(bytes.substr(8, n).find("\"__metadata__\":{\"note\":\"hello\"}") != std::string::npos);

  auto file = st::MappedFile::open(path);
  const auto& eb = file->at("b");
  const auto& ea = file->at("a");
  CHECK(eb.begin == 0);  // the given order, not alphabetical
  CHECK(ea.begin == sizeof b);
  CHECK(file->at("empty").numel() == 0);
  CHECK(std::memcmp(file->data(eb), b, sizeof b) == 0);
  CHECK(std::memcmp(file->data(ea), a, sizeof a) == 0);
  CHECK(file->header().metadata.at("note") == "hello");
  REQUIRE_THROWS_WITH(file->at("c"), FLAT_CONTAINS("no tensor \"c\"") && FLAT_CONTAINS(path));
}

TEST_CASE("writer rejects bad tensors, naming them", "[core][safetensors]") {
  auto dir = flat::test::scratch_dir("safetensors_writer_errors");
  const std::string path = (dir / "bad.safetensors").string();
  const float x[2] = {0.f, 1.f};
  REQUIRE_THROWS_WITH(st::write(path, {{"x", st::DType::F32, {3}, x, sizeof x}}),
                      FLAT_CONTAINS("tensor \"x\": size mismatch"));
  REQUIRE_THROWS_WITH(st::write(path, {{"x", st::DType::F32, {2}, x, sizeof x}, {"x", st::DType::F32, {2}, x, sizeof x}}),
                      FLAT_CONTAINS("\"x\": duplicate tensor name"));
  REQUIRE_THROWS_WITH(st::write(path, {{"__metadata__", st::DType::F32, {2}, x, sizeof x}}),
                      FLAT_CONTAINS("reserved"));
  REQUIRE_THROWS_WITH(st::write(path, {{"x", st::DType::F32, {-2}, x, sizeof x}}), FLAT_CONTAINS("negative dimension"));
  CHECK(!std::filesystem::exists(path));
}

TEST_CASE("opening missing, empty, folder and garbage files names the path", "[core][safetensors]") {
  auto dir = flat::test::scratch_dir("safetensors_open");
  const std::string missing = (dir / "missing.safetensors").string();
  REQUIRE_THROWS_WITH(st::MappedFile::open(missing), FLAT_CONTAINS(missing) && FLAT_CONTAINS("No such file"));
  REQUIRE_THROWS_WITH(st::MappedFile::open(dir.string()), FLAT_CONTAINS("is a directory"));

  const std::string empty = (dir / "empty.safetensors").string();
  std::ofstream(empty).close();
  REQUIRE_THROWS_WITH(st::MappedFile::open(empty), FLAT_CONTAINS(empty) && FLAT_CONTAINS("empty file"));

  const std::string garbage = (dir / "garbage.safetensors").string();
  std::ofstream(garbage) << "this is not a safetensors file at all";
  REQUIRE_THROWS_WITH(st::MappedFile::open(garbage), FLAT_CONTAINS(garbage) && FLAT_CONTAINS("100 MB"));

  if (::geteuid() != 0) {  // root reads anything
    const std::string locked = (dir / "locked.safetensors").string();
    st::write(locked, {});
    std::filesystem::permissions(locked, std::filesystem::perms::none);
    REQUIRE_THROWS_WITH(st::MappedFile::open(locked), FLAT_CONTAINS(locked) && FLAT_CONTAINS("Permission denied"));
  }
}
