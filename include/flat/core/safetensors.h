// safetensors format, torch-free (so the libFuzzer target needs no libtorch).
// Layout: u64 little-endian header length N, N bytes of UTF-8 JSON, data buffer.
// Every entry: {"dtype", "shape", "data_offsets": [begin, end)} relative to the
// buffer; optional "__metadata__" string->string map.
#pragma once
#include <cstddef>
#include <cstdint>
#include <functional>
#include <map>
#include <memory>
#include <optional>
#include <string>
#include <string_view>
#include <vector>

namespace flat::safetensors {

enum class DType : uint8_t { BOOL, U8, I8, I16, U16, I32, U32, I64, U64, F16, BF16, F32, F64, F8_E4M3, F8_E5M2 };

std::string_view dtype_name(DType dtype);              // "F32"
size_t dtype_size(DType dtype);                        // bytes per element
std::optional<DType> parse_dtype(std::string_view name);

struct Entry {
  std::string name;
  DType dtype;
  std::vector<int64_t> shape;
  uint64_t begin = 0;  // byte range in the data buffer, [begin, end)
  uint64_t end = 0;
  uint64_t numel() const;
};

struct Header {
  std::vector<Entry> entries;  // in data-offset order
  std::map<std::string, std::string> metadata;
  uint64_t data_start = 0;     // 8 + N: file offset of the data buffer
  std::map<std::string, size_t, std::less<>> by_name;  // name -> index in entries (filled by parse)
  const Entry* find(std::string_view name) const;
};

inline constexpr uint64_t kMaxHeaderBytes = 100ull * 1000 * 1000;  // as the reference loader

// Validates a whole file image: header length within the file and <= 100 MB,
// valid JSON object, known dtypes, shapes with non-negative dims, offsets in
// range, size == numel * itemsize, ranges contiguous from 0 to the end of the
// buffer without gaps or overlap, unique names, metadata of strings. Throws
// flat::Error("<label>: <what is wrong, naming the tensor>").
Header parse(const uint8_t* bytes, size_t size, const std::string& label);

// A read-only memory map of a safetensors file, validated on open.
class MappedFile {
 public:
  static std::shared_ptr<MappedFile> open(const std::string& path);  // throws flat::Error naming the path
  ~MappedFile();
  MappedFile(const MappedFile&) = delete;
  MappedFile& operator=(const MappedFile&) = delete;

  const std::string& path() const { return path_; }
  const Header& header() const { return header_; }
  const Entry& at(std::string_view name) const;         // throws naming file and tensor
  const uint8_t* data(const Entry& entry) const;        // pointer into the map

 private:
  MappedFile() = default;
  std::string path_;
  Header header_;
  const uint8_t* map_ = nullptr;
  size_t size_ = 0;
};

// A tensor to write: raw little-endian bytes in C order.
struct RawTensor {
  std::string name;
  DType dtype;
  std::vector<int64_t> shape;
  const void* data = nullptr;
  size_t nbytes = 0;
};

// Writes atomically (temp file in the same folder, then rename). Throws
// flat::Error on duplicate names or size mismatch, naming the tensor.
void write(const std::string& path, const std::vector<RawTensor>& tensors,
           const std::map<std::string, std::string>& metadata = {});

}  // namespace flat::safetensors
