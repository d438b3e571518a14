// The .npy reader and writer: files written by numpy (bytes embedded below),
// every format version, each defect refused with its own message naming the file.
#include <filesystem>
#include <fstream>
#include <string>

#include "flat/core/error.h"
#include "flat/core/npy.h"
#include "support/error_of.h"
#include "support/read_file.h"
#include "test_support.h"

using namespace flat;
namespace fs = std::filesystem;

namespace {

// numpy 2.4.6: np.save(f, np.array([[1.5, -2.0, 3.25], [0.0, 65504.0, -0.5]], dtype=np.float16))
const std::string kNumpyF2V1 = std::string("\x93NUMPY\x01\x00\x76\x00", 10) +
                               "{'descr': '<f2', 'fortran_order': False, 'shape': (2, 3), }" + std::string(58, ' ') +
                               std::string("\n\x00\x3e\x00\xc0\x80\x42\x00\x00\xff\x7b\x00\xb8", 13);
// numpy 2.4.6: np.lib.format.write_array(f, np.arange(6, dtype='<f4').reshape(3, 2, 1), version=(3, 0))
const std::string kNumpyF4V3 =
    std::string("\x93NUMPY\x03\x00\x74\x00\x00\x00", 12) +
    "{'descr': '<f4', 'fortran_order': False, 'shape': (3, 2, 1), }" + std::string(53, ' ') + "\n" +
    std::string("\x00\x00\x00\x00\x00\x00\x80\x3f\x00\x00\x00\x40\x00\x00\x40\x40\x00\x00\x80\x40\x00\x00\xa0\x40", 24);

// A file of format `major` with this header dict (padded like numpy) and data.
std::string npy_bytes(int major, const std::string& dict, const std::string& data) {
  const size_t len_bytes = major == 1 ? 2 : 4;
  std::string header = dict;
  const size_t total = 8 + len_bytes + header.size() + 1;
  header += std::string((64 - total % 64) % 64, ' ') + "\n";
  std::string out = std::string("\x93NUMPY", 6) + char(major) + char(0);
  for (size_t i = 0; i < len_bytes; ++i) out += char((header.size() >> (8 * i)) & 0xff);
  return out + header + data;
}

// A version-1 file whose header dict holds these descr, shape and fortran_order texts, then `extra` keys.
std::string npy_v1(const std::string& descr, const std::string& shape, const std::string& data,
                   const std::string& fortran = "False", const std::string& extra = "") {
  const std::string dict =
      "{'descr': " + descr + ", 'fortran_order': " + fortran + ", 'shape': " + shape + ", " + extra + "}";
  return npy_bytes(1, dict, data);
}

// The same file with the header's final '\n' turned into a space.
std::string without_newline(std::string bytes) {
  const size_t len = size_t(static_cast<unsigned char>(bytes[8])) | size_t(static_cast<unsigned char>(bytes[9])) << 8;
  bytes[10 + len - 1] = ' ';
  return bytes;
}

std::string floats(std::initializer_list<float> v) {
  return std::string(reinterpret_cast<const char*>(v.begin()), v.size() * sizeof(float));
}

fs::path put(const fs::path& dir, const std::string& name, const std::string& bytes) {
  std::ofstream(dir / name, std::ios::binary) << bytes;
  return dir / name;
}

std::string read_error(const fs::path& file) {
  return test::error_of([&] { read_npy(file.string()); });
}

}  // namespace

TEST_CASE("npy: files written by numpy read back with their values", "[npy]") {
  auto dir = test::scratch_dir("npy_numpy");
  REQUIRE(kNumpyF2V1.size() == 140);
  REQUIRE(kNumpyF4V3.size() == 152);
  auto a = read_npy(put(dir, "a.npy", kNumpyF2V1).string());
  CHECK(a.scalar_type() == at::kHalf);
  CHECK(a.sizes() == at::IntArrayRef({2, 3}));
  CHECK(at::equal(a.to(at::kFloat), at::tensor({1.5f, -2.0f, 3.25f, 0.0f, 65504.0f, -0.5f}).view({2, 3})));
  auto b = read_npy(put(dir, "b.npy", kNumpyF4V3).string());
  CHECK(b.scalar_type() == at::kFloat);
  CHECK(b.sizes() == at::IntArrayRef({3, 2, 1}));
  CHECK(at::equal(b, at::arange(6, at::kFloat).view({3, 2, 1})));
  // Our writer produces numpy's bytes exactly (same header text and padding).
  write_npy((dir / "w.npy").string(), a);
  CHECK(test::read_file(dir / "w.npy") == kNumpyF2V1);
}

TEST_CASE("npy: versions 1, 2 and 3, every supported dtype, round trips", "[npy]") {
  auto dir = test::scratch_dir("npy_versions");
  const std::string dict = "{'descr': '<f4', 'fortran_order': False, 'shape': (2, 2), }";
  for (int major : {1, 2, 3}) {
    auto t = read_npy(put(dir, "v" + std::to_string(major) + ".npy", npy_bytes(major, dict, floats({1, 2, 3, 4}))).string());
    CHECK(at::equal(t, at::tensor({1.f, 2.f, 3.f, 4.f}).view({2, 2})));
  }
  // Key order and spacing are free (a Python dict), Python 2 longs ("3L") are read.
  auto t = read_npy(put(dir, "order.npy", npy_bytes(1, "{'shape': (1L, 2L), 'fortran_order': False, \"descr\": '<f4'}",
                                                     floats({5, 6})))
                        .string());
  CHECK(at::equal(t, at::tensor({5.f, 6.f}).view({1, 2})));
  for (auto type : {at::kHalf, at::kFloat, at::kDouble, at::kChar, at::kShort, at::kInt, at::kLong, at::kByte}) {
    auto x = (at::arange(12, at::kDouble) - 3).view({3, 4}).to(type);
    if (type == at::kByte) x = at::arange(12, at::kDouble).view({3, 4}).to(type);
    write_npy((dir / "rt.npy").string(), x);
    auto y = read_npy((dir / "rt.npy").string());
    CHECK(y.scalar_type() == type);
    CHECK(at::equal(x, y));
  }
  auto flags = at::tensor({1, 0, 1}).to(at::kBool);
  write_npy((dir / "b.npy").string(), flags);
  CHECK(at::equal(read_npy((dir / "b.npy").string()), flags));
  auto scalar = at::scalar_tensor(2.5, at::kDouble);
  write_npy((dir / "s.npy").string(), scalar);
  auto s = read_npy((dir / "s.npy").string());
  CHECK(s.dim() == 0);
  CHECK(s.item<double>() == 2.5);
  // A non-contiguous tensor is written in C order.
  auto nc = at::arange(6, at::kFloat).view({2, 3}).t();
  write_npy((dir / "t.npy").string(), nc);
  CHECK(at::equal(read_npy((dir / "t.npy").string()), nc.contiguous()));
}

TEST_CASE("npy: every defect is refused with its own message naming the file", "[npy]") {
  auto dir = test::scratch_dir("npy_defects");
  const std::string ok_data = floats({1, 2, 3, 4});
  struct Case {
    const char* name;
    std::string bytes;
    const char* message;
  };
  const std::vector<Case> cases = {
      {"magic.npy", "NUMPY\x01\x00 not numpy at all", "not a .npy file"},
      {"version.npy", npy_v1("'<f4'", "(2, 2)", ok_data).replace(6, 1, "\x04"), "format version 4.0 is not supported"},
      {"fortran.npy", npy_v1("'<f4'", "(2, 2)", ok_data, "True"), "Fortran (column-major) order"},
      {"bigendian.npy", npy_v1("'>f4'", "(2, 2)", ok_data), "big-endian"},
      {"complex.npy", npy_v1("'<c8'", "(2,)", ok_data), "dtype '<c8' is not supported"},
      {"struct.npy", npy_v1("[('x', '<f4')]", "(2,)", ok_data), "expected a quoted string"},
      {"extra_key.npy", npy_v1("'<f4'", "(2, 2)", ok_data, "False", "'extra': 1, "), "unexpected key 'extra'"},
      {"twice.npy", npy_bytes(1, "{'descr': '<f4', 'descr': '<f4', 'fortran_order': False, 'shape': (4,), }", ok_data),
       "key 'descr' given twice"},
      {"no_shape.npy", npy_bytes(1, "{'descr': '<f4', 'fortran_order': False, }", ok_data), "missing key 'shape'"},
      {"not_tuple.npy", npy_v1("'<f4'", "(4)", ok_data), "is not a tuple"},
      {"negative.npy", npy_v1("'<f4'", "(-4,)", ok_data), "tuple of non-negative integers"},
      {"truncated.npy", npy_v1("'<f4'", "(2, 3)", ok_data),
       "truncated: shape (2,3) of '<f4' needs 24 data bytes, the file holds 16"},
      {"long.npy", npy_v1("'<f4'", "(3,)", ok_data), "4 bytes after the array"},
      {"header_cut.npy", npy_v1("'<f4'", "(2, 2)", "").substr(0, 40), "truncated in its header"},
      {"no_newline.npy", without_newline(npy_v1("'<f4'", "(1,)", floats({1}))), "does not end with a newline"},
      {"bool.npy", npy_v1("'|b1'", "(2,)", "\x01\x02"), "bool array holds a byte other than 0 or 1"},
      {"huge.npy", npy_v1("'<f8'", "(4294967296, 4294967296)", ok_data), "is too large"},
  };
  for (const auto& c : cases) {
    INFO(c.name);
    const std::string msg = read_error(put(dir, c.name, c.bytes));
    CHECK_THAT(msg, FLAT_CONTAINS(c.message));
    CHECK_THAT(msg, FLAT_CONTAINS(c.name));
  }
  // A 1-D array marked Fortran order is the same bytes: accepted.
  auto one_d = read_npy(put(dir, "f1d.npy", npy_v1("'<f4'", "(4,)", ok_data, "True")).string());
  CHECK(at::equal(one_d, at::tensor({1.f, 2.f, 3.f, 4.f})));
  CHECK_THAT(read_error(dir / "missing.npy"), FLAT_CONTAINS("missing.npy: cannot open .npy file"));
}
