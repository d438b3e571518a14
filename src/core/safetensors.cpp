// safetensors reader/writer without libtorch (it is also compiled into the
// libFuzzer target). The parser trusts nothing in the file: every length,
// offset and shape is checked before it is used, and every failure is a
// flat::Error that names the file and the tensor.
#include "flat/core/safetensors.h"

#include <fcntl.h>
#include <sys/mman.h>
#include <sys/stat.h>
#include <unistd.h>

#include <algorithm>
#include <cerrno>
#include <cstring>
#include <limits>
#include <set>
#include <tuple>

#include <nlohmann/json.hpp>

#include "flat/core/atomic_file.h"
#include "flat/core/error.h"

#if defined(__BYTE_ORDER__) && __BYTE_ORDER__ != __ORDER_LITTLE_ENDIAN__
#error "safetensors data is little-endian; this reader assumes a little-endian host"
#endif

namespace flat::safetensors {
namespace {

using json = nlohmann::json;

struct DTypeInfo {
  DType dtype;
  std::string_view name;
  size_t size;
};

// The format's dtype names, in the order of the DType enum.
constexpr DTypeInfo kDTypes[] = {
    {DType::BOOL, "BOOL", 1}, {DType::U8, "U8", 1},     {DType::I8, "I8", 1},
    {DType::I16, "I16", 2},   {DType::U16, "U16", 2},   {DType::I32, "I32", 4},
    {DType::U32, "U32", 4},   {DType::I64, "I64", 8},   {DType::U64, "U64", 8},
    {DType::F16, "F16", 2},   {DType::BF16, "BF16", 2}, {DType::F32, "F32", 4},
    {DType::F64, "F64", 8},   {DType::F8_E4M3, "F8_E4M3", 1}, {DType::F8_E5M2, "F8_E5M2", 1},
};

const DTypeInfo& info(DType dtype) {
  auto i = static_cast<size_t>(dtype);
  if (i >= std::size(kDTypes)) fail("safetensors: invalid DType value " + std::to_string(i));
  return kDTypes[i];
}

std::string in_quotes(const std::string& name) { return "\"" + name + "\""; }

std::string shape_text(const std::vector<int64_t>& shape) {
  std::string s = "(";
  for (size_t i = 0; i < shape.size(); ++i) s += (i ? "," : "") + std::to_string(shape[i]);
  return s + ")";
}

std::string range_text(uint64_t begin, uint64_t end) {
  return "[" + std::to_string(begin) + ", " + std::to_string(end) + ")";
}

// numel * itemsize, or nullopt on uint64 overflow. Dims are multiplied in file
// order (as the reference loader does), and the element count must also fit
// libtorch's int64 sizes.
std::optional<uint64_t> checked_nbytes(const std::vector<int64_t>& shape, size_t itemsize) {
  uint64_t numel = 1;
  for (int64_t d : shape) {
    if (__builtin_mul_overflow(numel, static_cast<uint64_t>(d), &numel)) return std::nullopt;
  }
  if (numel > static_cast<uint64_t>(std::numeric_limits<int64_t>::max())) return std::nullopt;
  uint64_t bytes = 0;
  if (__builtin_mul_overflow(numel, static_cast<uint64_t>(itemsize), &bytes)) return std::nullopt;
  return bytes;
}

constexpr size_t kMaxJsonDepth = 64;

// A first, DOM-free pass over the header JSON (nlohmann SAX interface). It
// finds what nlohmann's DOM parser would let through or handle badly:
// duplicate object keys (the DOM keeps the last one silently) and deep
// nesting (a valid header nests 3 levels: header, entry, shape; refusing more
// keeps a hostile 100 MB "[[[[..." from costing gigabytes). Returning false
// stops the parse at the first problem.
class HeaderScan {
 public:
  std::string problem;  // empty if the JSON is fine

  bool null() { return true; }
  bool boolean(bool) { return true; }
  bool number_integer(json::number_integer_t) { return true; }
  bool number_unsigned(json::number_unsigned_t) { return true; }
  bool number_float(json::number_float_t, const json::string_t&) { return true; }
  bool string(json::string_t&) { return true; }
  bool binary(json::binary_t&) { return true; }
  bool start_object(std::size_t) { return open(true); }
  bool start_array(std::size_t) { return open(false); }
  bool end_object() { return close(); }
  bool end_array() { return close(); }
  bool key(json::string_t& key) {
    auto& top = open_.back();
    if (!top.keys.insert(key).second) {
      problem = "duplicate key " + in_quotes(key);
      if (open_.size() >= 2 && open_.end()[-2].is_object) problem += " inside " + in_quotes(open_.end()[-2].last_key);
      problem += " in the header (names must be unique)";
      return false;
    }
    top.last_key = key;
    return true;
  }
  bool parse_error(std::size_t, const std::string&, const nlohmann::detail::exception& e) {
    problem = std::string("header is not valid JSON (") + e.what() + ")";
    return false;
  }

 private:
  struct Open {
    bool is_object;
    std::set<std::string> keys;
    std::string last_key;
  };
  std::vector<Open> open_;

  bool open(bool is_object) {
    if (open_.size() >= kMaxJsonDepth) {
      problem = "header JSON nests deeper than " + std::to_string(kMaxJsonDepth) + " levels";
      return false;
    }
    open_.push_back({is_object, {}, {}});
    return true;
  }
  bool close() {
    open_.pop_back();
    return true;
  }
};

// Scans, then builds the DOM (linear time; nlohmann's callback parser is
// quadratic in the number of entries).
json parse_json(const char* begin, const char* end, const std::string& label) {
  HeaderScan scan;
  bool ok = false;
  try {
    ok = json::sax_parse(begin, end, &scan);
  } catch (const json::exception& e) {
    fail(label + ": header is not valid JSON (" + e.what() + ")");
  }
  if (!ok || !scan.problem.empty()) {
    fail(label + ": " + (scan.problem.empty() ? std::string("header is not valid JSON") : scan.problem));
  }
  try {
    return json::parse(begin, end);
  } catch (const json::exception& e) {
    fail(label + ": header is not valid JSON (" + e.what() + ")");
  }
}

std::map<std::string, std::string> parse_metadata(const json& value, const std::string& label) {
  if (!value.is_object()) fail(label + ": __metadata__ must be an object mapping strings to strings");
  std::map<std::string, std::string> metadata;
  for (const auto& [key, v] : value.items()) {
    if (!v.is_string()) fail(label + ": __metadata__ key " + in_quotes(key) + " must map to a string, got " + v.type_name());
    metadata[key] = v.get<std::string>();
  }
  return metadata;
}

// One tensor entry: dtype, shape and offsets are checked for type and range;
// the offsets against the buffer size; the byte count against shape x dtype.
Entry parse_entry(const std::string& name, const json& value, uint64_t buffer_size, const std::string& label) {
  const std::string where = label + ": tensor " + in_quotes(name);
  if (!value.is_object()) fail(where + ": entry must be an object, got " + value.type_name());
  Entry entry;
  entry.name = name;

  auto dtype_it = value.find("dtype");
  if (dtype_it == value.end()) fail(where + ": missing \"dtype\"");
  if (!dtype_it->is_string()) fail(where + ": \"dtype\" must be a string, got " + dtype_it->type_name());
  const auto& dtype_text = dtype_it->get_ref<const std::string&>();
  auto dtype = parse_dtype(dtype_text);
  if (!dtype) fail(where + ": unknown dtype " + in_quotes(dtype_text));
  entry.dtype = *dtype;

  auto shape_it = value.find("shape");
  if (shape_it == value.end()) fail(where + ": missing \"shape\"");
  if (!shape_it->is_array()) fail(where + ": \"shape\" must be an array, got " + shape_it->type_name());
  for (const auto& dim : *shape_it) {
    if (dim.is_number_integer() && !dim.is_number_unsigned()) {
      fail(where + ": negative dimension " + dim.dump() + " in \"shape\"");
    }
    if (!dim.is_number_unsigned()) fail(where + ": \"shape\" must hold non-negative integers, got " + dim.dump());
    auto d = dim.get<uint64_t>();
    if (d > static_cast<uint64_t>(std::numeric_limits<int64_t>::max())) {
      fail(where + ": dimension " + std::to_string(d) + " in \"shape\" overflows int64");
    }
    entry.shape.push_back(static_cast<int64_t>(d));
  }

  auto offsets_it = value.find("data_offsets");
  if (offsets_it == value.end()) fail(where + ": missing \"data_offsets\"");
  const json& offsets = *offsets_it;
  if (!offsets.is_array() || offsets.size() != 2 || !offsets[0].is_number_unsigned() ||
      !offsets[1].is_number_unsigned()) {
    fail(where + ": \"data_offsets\" must be [begin, end] with non-negative integers, got " + offsets.dump());
  }
  entry.begin = offsets[0].get<uint64_t>();
  entry.end = offsets[1].get<uint64_t>();
  if (entry.begin > entry.end) fail(where + ": data_offsets " + range_text(entry.begin, entry.end) + " have begin > end");
  if (entry.end > buffer_size) {
    fail(where + ": data_offsets " + range_text(entry.begin, entry.end) + " out of range of the " +
         std::to_string(buffer_size) + "-byte data buffer");
  }

  auto nbytes = checked_nbytes(entry.shape, dtype_size(entry.dtype));
  if (!nbytes) fail(where + ": shape " + shape_text(entry.shape) + " overflows (element count too large)");
  if (entry.end - entry.begin != *nbytes) {
    fail(where + ": size mismatch: data_offsets " + range_text(entry.begin, entry.end) + " hold " +
         std::to_string(entry.end - entry.begin) + " bytes but shape " + shape_text(entry.shape) + " of " +
         std::string(dtype_name(entry.dtype)) + " needs " + std::to_string(*nbytes));
  }
  return entry;
}

// The ranges must tile [0, buffer_size) exactly: sorted by offset, each one
// starts where the previous one ended (zero-size tensors are empty ranges).
void check_tiling(std::vector<Entry>& entries, uint64_t buffer_size, const std::string& label) {
  std::sort(entries.begin(), entries.end(), [](const Entry& a, const Entry& b) {
    return std::tie(a.begin, a.end, a.name) < std::tie(b.begin, b.end, b.name);
  });
  uint64_t cursor = 0;
  const Entry* previous = nullptr;
  for (const auto& e : entries) {
    if (e.begin < cursor) {
      fail(label + ": tensors " + in_quotes(previous->name) + " " + range_text(previous->begin, previous->end) + " and " +
           in_quotes(e.name) + " " + range_text(e.begin, e.end) + " overlap");
    }
    if (e.begin > cursor) {
      fail(label + ": gap in the data buffer: bytes " + range_text(cursor, e.begin) + " before tensor " +
           in_quotes(e.name) + " belong to no tensor");
    }
    cursor = e.end;
    previous = &e;
  }
  if (cursor != buffer_size) {
    fail(label + ": gap in the data buffer: " + std::to_string(buffer_size - cursor) + " trailing bytes after the last tensor" +
         (previous ? " " + in_quotes(previous->name) : std::string()) + " (buffer " + range_text(cursor, buffer_size) +
         " unused)");
  }
}

}  // namespace

std::string_view dtype_name(DType dtype) { return info(dtype).name; }
size_t dtype_size(DType dtype) { return info(dtype).size; }

std::optional<DType> parse_dtype(std::string_view name) {
  for (const auto& d : kDTypes) {
    if (d.name == name) return d.dtype;
  }
  return std::nullopt;
}

uint64_t Entry::numel() const {
  uint64_t n = 1;
  for (int64_t d : shape) n *= static_cast<uint64_t>(d);  // parse() has checked it does not overflow
  return n;
}

const Entry* Header::find(std::string_view name) const {
  if (by_name.size() == entries.size()) {  // the index parse() builds
    auto it = by_name.find(name);
    return it == by_name.end() ? nullptr : &entries[it->second];
  }
  for (const auto& e : entries) {
    if (e.name == name) return &e;
  }
  return nullptr;
}

Header parse(const uint8_t* bytes, size_t size, const std::string& label) {
  if (size < 8) {
    fail(label + ": truncated file: " + std::to_string(size) +
         " bytes, shorter than the 8-byte header length that starts a safetensors file");
  }
  uint64_t header_len = 0;
  for (int i = 7; i >= 0; --i) header_len = (header_len << 8) | bytes[i];  // little-endian u64
  // A PyTorch checkpoint (torch.save: a zip archive, or a pickle before 1.6),
  // such as Wan's official Wan2.1_VAE.pth: its first bytes read as an
  // impossible header length; say what it is and what to do.
  const bool zip = bytes[0] == 'P' && bytes[1] == 'K' && bytes[2] == 3 && bytes[3] == 4;
  const bool pickle = bytes[0] == 0x80 && bytes[1] >= 2 && bytes[1] <= 5;
  if ((zip || pickle) && (header_len > kMaxHeaderBytes || header_len > size - 8))
    fail(label + ": a PyTorch checkpoint (torch.save, e.g. an official .pth), not a safetensors file: convert it "
         "once with the Python line in docs/model.md (\"Converting the original .pth\")");
  if (header_len > kMaxHeaderBytes) {
    fail(label + ": header length " + std::to_string(header_len) + " exceeds the 100 MB limit (not a safetensors file?)");
  }
  if (header_len > size - 8) {
    fail(label + ": truncated file: header length " + std::to_string(header_len) + " runs past the end of the file (" +
         std::to_string(size) + " bytes)");
  }

  const char* text = reinterpret_cast<const char*>(bytes + 8);
  json root = parse_json(text, text + header_len, label);
  if (!root.is_object()) fail(label + ": header JSON must be an object, got " + std::string(root.type_name()));

  Header header;
  header.data_start = 8 + header_len;
  const uint64_t buffer_size = size - header.data_start;
  for (const auto& [name, value] : root.items()) {
    if (name == "__metadata__") {
      header.metadata = parse_metadata(value, label);
    } else {
      header.entries.push_back(parse_entry(name, value, buffer_size, label));
    }
  }
  check_tiling(header.entries, buffer_size, label);
  for (size_t i = 0; i < header.entries.size(); ++i) header.by_name.emplace(header.entries[i].name, i);
  return header;
}

// ---------------------------------------------------------------------------
// MappedFile

std::shared_ptr<MappedFile> MappedFile::open(const std::string& path) {
  std::shared_ptr<MappedFile> file(new MappedFile());
  file->path_ = path;

  int fd = ::open(path.c_str(), O_RDONLY | O_CLOEXEC);
  if (fd < 0) fail(path + ": cannot open safetensors file: " + std::strerror(errno));
  struct stat st {};
  if (::fstat(fd, &st) != 0) {
    int err = errno;
    ::close(fd);
    fail(path + ": cannot stat safetensors file: " + std::strerror(err));
  }
  if (S_ISDIR(st.st_mode)) {
    ::close(fd);
    fail(path + ": is a directory, expected a safetensors file");
  }
  if (!S_ISREG(st.st_mode)) {
    ::close(fd);
    fail(path + ": not a regular file, expected a safetensors file");
  }
  if (st.st_size == 0) {
    ::close(fd);
    fail(path + ": empty file (0 bytes), expected a safetensors file");
  }
  size_t size = static_cast<size_t>(st.st_size);
  void* map = ::mmap(nullptr, size, PROT_READ, MAP_PRIVATE, fd, 0);
  int map_errno = errno;
  ::close(fd);  // the mapping keeps the file alive
  if (map == MAP_FAILED) fail(path + ": cannot memory-map safetensors file: " + std::strerror(map_errno));
  file->map_ = static_cast<const uint8_t*>(map);
  file->size_ = size;

  file->header_ = parse(file->map_, file->size_, path);  // on failure ~MappedFile unmaps
  return file;
}

MappedFile::~MappedFile() {
  if (map_) ::munmap(const_cast<uint8_t*>(map_), size_);
}

const Entry& MappedFile::at(std::string_view name) const {
  if (const Entry* e = header_.find(name)) return *e;
  std::string names;
  size_t shown = 0;
  for (const auto& e : header_.entries) {
    if (shown++ == 8) {
      names += ", ...";
      break;
    }
    names += (names.empty() ? "" : ", ") + e.name;
  }
  fail(path_ + ": no tensor " + in_quotes(std::string(name)) + " (the file holds " +
       std::to_string(header_.entries.size()) + " tensor(s)" + (names.empty() ? "" : ": " + names) + ")");
}

const uint8_t* MappedFile::data(const Entry& entry) const { return map_ + header_.data_start + entry.begin; }

// ---------------------------------------------------------------------------
// Writer

void write(const std::string& path, const std::vector<RawTensor>& tensors,
           const std::map<std::string, std::string>& metadata) {
  json header = json::object();
  std::set<std::string> names;
  uint64_t offset = 0;
  for (const auto& t : tensors) {
    const std::string where = path + ": tensor " + in_quotes(t.name);
    if (t.name.empty()) fail(path + ": a tensor has an empty name");
    if (t.name == "__metadata__") fail(where + ": the name is reserved for metadata");
    if (!names.insert(t.name).second) fail(where + ": duplicate tensor name");
    for (int64_t d : t.shape) {
      if (d < 0) fail(where + ": negative dimension in shape " + shape_text(t.shape));
    }
    auto nbytes = checked_nbytes(t.shape, dtype_size(t.dtype));
    if (!nbytes) fail(where + ": shape " + shape_text(t.shape) + " overflows");
    if (*nbytes != t.nbytes) {
      fail(where + ": size mismatch: shape " + shape_text(t.shape) + " of " + std::string(dtype_name(t.dtype)) +
           " needs " + std::to_string(*nbytes) + " bytes, got " + std::to_string(t.nbytes));
    }
    if (t.nbytes > 0 && t.data == nullptr) fail(where + ": null data pointer");
    header[t.name] = {{"dtype", std::string(dtype_name(t.dtype))},
                      {"shape", t.shape},
                      {"data_offsets", json::array({offset, offset + t.nbytes})}};
    offset += t.nbytes;
  }
  if (!metadata.empty()) header["__metadata__"] = metadata;

  std::string text;
  try {
    text = header.dump();
  } catch (const json::exception& e) {
    fail(path + ": tensor names and metadata must be valid UTF-8 (" + e.what() + ")");
  }
  // Pad with spaces to a multiple of 8 so the data buffer starts aligned (as
  // the reference writer does); JSON allows trailing whitespace.
  text.append((8 - text.size() % 8) % 8, ' ');

  AtomicFile file(path);
  auto& out = file.stream();
  uint64_t n = text.size();
  char length[8];
  for (int i = 0; i < 8; ++i) length[i] = static_cast<char>((n >> (8 * i)) & 0xff);
  out.write(length, 8);
  out.write(text.data(), static_cast<std::streamsize>(text.size()));
  for (const auto& t : tensors) {
    if (t.nbytes > 0) out.write(static_cast<const char*>(t.data), static_cast<std::streamsize>(t.nbytes));
  }
  file.commit();
}

}  // namespace flat::safetensors
