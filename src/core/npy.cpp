// NumPy .npy reader and writer (see include/flat/core/npy.h for why our own).
#include "flat/core/npy.h"

#include <cctype>
#include <cstring>
#include <fstream>
#include <iterator>
#include <limits>

#include "flat/core/atomic_file.h"
#include "flat/core/error.h"
#include "flat/core/shape.h"

namespace flat {

namespace {

constexpr char kMagic[] = "\x93NUMPY";
constexpr size_t kMagicSize = 6;

static_assert(__BYTE_ORDER__ == __ORDER_LITTLE_ENDIAN__, "the .npy reader assumes a little-endian host");

// The header dict: a tiny, strict reader of the Python literal numpy writes.
class DictParser {
 public:
  DictParser(const std::string& text, const std::string& where) : s_(text), where_(where) {}

  void parse(NpyHeader& h) {
    bool has_descr = false, has_fortran = false, has_shape = false;
    skip_space();
    expect('{');
    for (;;) {
      skip_space();
      if (peek() == '}') {
        ++pos_;
        break;
      }
      const std::string key = string_literal();
      skip_space();
      expect(':');
      skip_space();
      if (key == "descr") {
        if (has_descr) bad("key 'descr' given twice");
        has_descr = true;
        h.descr = string_literal();
      } else if (key == "fortran_order") {
        if (has_fortran) bad("key 'fortran_order' given twice");
        has_fortran = true;
        h.fortran_order = boolean();
      } else if (key == "shape") {
        if (has_shape) bad("key 'shape' given twice");
        has_shape = true;
        h.shape = tuple();
      } else {
        bad("unexpected key '" + key + "' (a .npy header holds exactly 'descr', 'fortran_order' and 'shape')");
      }
      skip_space();
      if (peek() == ',') {
        ++pos_;
        continue;
      }
      skip_space();
      if (peek() == '}') {
        ++pos_;
        break;
      }
      bad("expected ',' or '}' at offset " + std::to_string(pos_));
    }
    if (!has_descr || !has_fortran || !has_shape)
      bad(std::string("missing key '") + (!has_descr ? "descr" : !has_fortran ? "fortran_order" : "shape") + "'");
    // numpy pads with spaces and ends the header with '\n'.
    if (s_.empty() || s_.back() != '\n') bad("the header does not end with a newline");
    for (size_t i = pos_; i + 1 < s_.size(); ++i)
      if (s_[i] != ' ' && s_[i] != '\t') bad("unexpected text after the header dict at offset " + std::to_string(i));
  }

 private:
  [[noreturn]] void bad(const std::string& what) const { fail(where_ + ": invalid .npy header: " + what); }
  char peek() const { return pos_ < s_.size() ? s_[pos_] : '\0'; }
  void skip_space() {
    while (pos_ < s_.size() && (s_[pos_] == ' ' || s_[pos_] == '\t' || s_[pos_] == '\n' || s_[pos_] == '\r')) ++pos_;
  }
  void expect(char c) {
    if (peek() != c) bad(std::string("expected '") + c + "' at offset " + std::to_string(pos_));
    ++pos_;
  }
  std::string string_literal() {
    const char q = peek();
    if (q != '\'' && q != '"') bad("expected a quoted string at offset " + std::to_string(pos_));
    const size_t start = ++pos_;
    while (pos_ < s_.size() && s_[pos_] != q) {
      if (s_[pos_] == '\\' || s_[pos_] == '\n') bad("unsupported character in a string at offset " + std::to_string(pos_));
      ++pos_;
    }
    if (pos_ >= s_.size()) bad("unterminated string");
    return s_.substr(start, pos_++ - start);
  }
  bool boolean() {
    if (s_.compare(pos_, 4, "True") == 0) {
      pos_ += 4;
      return true;
    }
    if (s_.compare(pos_, 5, "False") == 0) {
      pos_ += 5;
      return false;
    }
    bad("'fortran_order' must be True or False");
  }
  std::vector<int64_t> tuple() {
    std::vector<int64_t> dims;
    expect('(');
    bool trailing_comma = false;
    for (;;) {
      skip_space();
      if (peek() == ')') {
        ++pos_;
        break;
      }
      if (!std::isdigit(static_cast<unsigned char>(peek())))
        bad("'shape' must be a tuple of non-negative integers (offset " + std::to_string(pos_) + ")");
      int64_t v = 0;
      while (std::isdigit(static_cast<unsigned char>(peek()))) {
        const int d = peek() - '0';
        if (v > (std::numeric_limits<int64_t>::max() - d) / 10) bad("a dimension of 'shape' is too large");
        v = v * 10 + d;
        ++pos_;
      }
      if (peek() == 'L') ++pos_;  // Python 2 longs (old numpy)
      dims.push_back(v);
      skip_space();
      trailing_comma = false;
      if (peek() == ',') {
        ++pos_;
        trailing_comma = true;
      } else if (peek() != ')') {
        bad("expected ',' or ')' in 'shape' at offset " + std::to_string(pos_));
      }
    }
    // "(5)" is the integer 5 in Python, not a tuple: numpy never writes it.
    if (dims.size() == 1 && !trailing_comma) bad("'shape' (n) is not a tuple (numpy writes (n,))");
    return dims;
  }

  const std::string& s_;
  const std::string& where_;
  size_t pos_ = 0;
};

at::ScalarType scalar_type(const NpyHeader& h) {
  switch (h.kind) {
    case 'f':
      return h.itemsize == 2 ? at::kHalf : h.itemsize == 4 ? at::kFloat : at::kDouble;
    case 'i':
      return h.itemsize == 1 ? at::kChar : h.itemsize == 2 ? at::kShort : h.itemsize == 4 ? at::kInt : at::kLong;
    case 'u':
      return at::kByte;
    default:
      return at::kBool;
  }
}

std::string descr_of(at::ScalarType t) {
  switch (t) {
    case at::kHalf: return "<f2";
    case at::kFloat: return "<f4";
    case at::kDouble: return "<f8";
    case at::kChar: return "|i1";
    case at::kShort: return "<i2";
    case at::kInt: return "<i4";
    case at::kLong: return "<i8";
    case at::kByte: return "|u1";
    case at::kBool: return "|b1";
    default: return "";
  }
}

}  // namespace

int64_t NpyHeader::numel() const {
  int64_t n = 1;
  for (int64_t d : shape) n *= d;
  return n;
}

NpyHeader parse_npy_header(const char* data, size_t size, const std::string& where) {
  if (size < kMagicSize + 2 || std::memcmp(data, kMagic, kMagicSize) != 0)
    fail(where + ": not a .npy file (no \\x93NUMPY magic)");
  NpyHeader h;
  h.major = static_cast<unsigned char>(data[6]);
  h.minor = static_cast<unsigned char>(data[7]);
  if (!((h.major == 1 || h.major == 2 || h.major == 3) && h.minor == 0))
    fail(where + ": .npy format version " + std::to_string(h.major) + "." + std::to_string(h.minor) +
         " is not supported (1.0, 2.0, 3.0)");
  const size_t len_bytes = h.major == 1 ? 2 : 4;
  if (size < 8 + len_bytes) fail(where + ": .npy file truncated in its header");
  uint64_t header_len = 0;
  for (size_t i = 0; i < len_bytes; ++i) header_len |= uint64_t(static_cast<unsigned char>(data[8 + i])) << (8 * i);
  h.data_offset = int64_t(8 + len_bytes + header_len);
  if (size_t(h.data_offset) > size)
    fail(where + ": .npy file truncated in its header (header of " + std::to_string(header_len) + " bytes)");
  const std::string text(data + 8 + len_bytes, size_t(header_len));
  DictParser(text, where).parse(h);

  // descr: byte order, kind, item size ("<f4"); structured and object dtypes are refused.
  const std::string& d = h.descr;
  bool simple = d.size() >= 3 && d.size() <= 5 && (d[0] == '<' || d[0] == '>' || d[0] == '|' || d[0] == '=');
  for (size_t i = 2; simple && i < d.size(); ++i) simple = std::isdigit(static_cast<unsigned char>(d[i])) != 0;
  if (!simple) fail(where + ": .npy dtype '" + d + "' is not supported (a plain number type such as '<f4')");
  h.kind = d[1];
  h.itemsize = std::stoll(d.substr(2));
  const bool supported = (h.kind == 'f' && (h.itemsize == 2 || h.itemsize == 4 || h.itemsize == 8)) ||
                          (h.kind == 'i' && (h.itemsize == 1 || h.itemsize == 2 || h.itemsize == 4 || h.itemsize == 8)) ||
                          (h.kind == 'u' && h.itemsize == 1) || (h.kind == 'b' && h.itemsize == 1);
  if (!supported)
    fail(where + ": .npy dtype '" + d +
         "' is not supported (float16/32/64, int8/16/32/64, uint8 or bool)");
  if (d[0] == '>' && h.itemsize > 1)
    fail(where + ": .npy data is big-endian ('" + d + "'); re-save it little-endian (arr.astype('<" + d.substr(1) +
         "'))");
  // Sizes: the product must not overflow (the file size check follows in read_npy).
  int64_t n = 1;
  for (int64_t dim : h.shape) {
    if (dim != 0 && n > std::numeric_limits<int64_t>::max() / h.itemsize / dim)
      fail(where + ": .npy shape " + shape_str(h.shape) + " is too large");
    n *= dim;
  }
  return h;
}

at::Tensor read_npy(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  if (!in) fail(path + ": cannot open .npy file");
  std::string bytes((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
  if (in.bad()) fail(path + ": cannot read .npy file");
  const NpyHeader h = parse_npy_header(bytes.data(), bytes.size(), path);
  int64_t big_dims = 0;
  for (int64_t dim : h.shape) big_dims += dim > 1;
  if (h.fortran_order && big_dims > 1)
    fail(path + ": .npy array of shape " + shape_str(h.shape) +
         " is in Fortran (column-major) order; re-save it in C order (numpy.ascontiguousarray)");
  const int64_t want = h.numel() * h.itemsize, have = int64_t(bytes.size()) - h.data_offset;
  if (have < want)
    fail(path + ": .npy file truncated: shape " + shape_str(h.shape) + " of '" + h.descr + "' needs " +
         std::to_string(want) + " data bytes, the file holds " + std::to_string(have));
  if (have > want)
    fail(path + ": .npy file has " + std::to_string(have - want) + " bytes after the array of shape " +
         shape_str(h.shape) + " ('" + h.descr + "')");
  auto t = at::empty(h.shape, at::TensorOptions().dtype(scalar_type(h)));
  if (h.kind == 'b')
    for (int64_t i = 0; i < want; ++i)
      if (static_cast<unsigned char>(bytes[size_t(h.data_offset + i)]) > 1)
        fail(path + ": .npy bool array holds a byte other than 0 or 1");
  if (want > 0) std::memcpy(t.data_ptr(), bytes.data() + h.data_offset, size_t(want));
  return t;
}

void write_npy(const std::string& path, const at::Tensor& tensor) {
  FLAT_CHECK(tensor.defined(), path + ": write_npy: undefined tensor");
  const std::string descr = descr_of(tensor.scalar_type());
  if (descr.empty()) fail(path + ": write_npy: dtype " + std::string(c10::toString(tensor.scalar_type())) + " not supported");
  auto t = tensor.detach().cpu().contiguous();
  std::string shape = "(";
  for (int64_t i = 0; i < t.dim(); ++i) shape += std::to_string(t.size(i)) + (t.dim() == 1 ? "," : i + 1 < t.dim() ? ", " : "");
  shape += ")";
  std::string header = "{'descr': '" + descr + "', 'fortran_order': False, 'shape': " + shape + ", }";
  // Pad so that magic + version + length + header is a multiple of 64, ending in '\n'.
  const size_t total = kMagicSize + 2 + 2 + header.size() + 1;
  header += std::string((64 - total % 64) % 64, ' ') + "\n";
  FLAT_CHECK(header.size() <= 65535, path + ": write_npy: header too long");
  std::string out(kMagic, kMagicSize);
  out += char(1);
  out += char(0);
  out += char(header.size() & 0xff);
  out += char(header.size() >> 8);
  out += header;
  out.append(static_cast<const char*>(t.data_ptr()), size_t(t.numel() * t.element_size()));
  write_file_atomic(path, out);
}

}  // namespace flat
