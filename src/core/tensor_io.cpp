// safetensors <-> at::Tensor on top of the torch-free reader/writer.
#include "flat/core/tensor_io.h"

#include <cstring>

#include "flat/core/error.h"
#include "flat/core/shape.h"

namespace flat {
namespace {

using safetensors::DType;

// Every dtype of the format has a libtorch counterpart (unsigned 16/32/64 bit
// since libtorch 2.3).
constexpr std::pair<DType, at::ScalarType> kScalarTypes[] = {
    {DType::BOOL, at::kBool},           {DType::U8, at::kByte},          {DType::I8, at::kChar},
    {DType::I16, at::kShort},           {DType::U16, at::kUInt16},       {DType::I32, at::kInt},
    {DType::U32, at::kUInt32},          {DType::I64, at::kLong},         {DType::U64, at::kUInt64},
    {DType::F16, at::kHalf},            {DType::BF16, at::kBFloat16},    {DType::F32, at::kFloat},
    {DType::F64, at::kDouble},          {DType::F8_E4M3, at::kFloat8_e4m3fn}, {DType::F8_E5M2, at::kFloat8_e5m2},
};

at::ScalarType to_scalar_type(DType dtype) {
  for (const auto& [d, s] : kScalarTypes) {
    if (d == dtype) return s;
  }
  fail("safetensors: dtype " + std::string(safetensors::dtype_name(dtype)) + " has no libtorch counterpart");
}

std::optional<DType> to_dtype(at::ScalarType type) {
  for (const auto& [d, s] : kScalarTypes) {
    if (s == type) return d;
  }
  return std::nullopt;
}

}  // namespace

at::Tensor read_tensor(const safetensors::MappedFile& file, const std::string& name) {
  const auto& entry = file.at(name);
  // at::empty gives an owned, allocator-aligned buffer; the mapped bytes may
  // sit at any offset in the file, so they are copied rather than wrapped.
  auto tensor = at::empty(entry.shape, at::TensorOptions().dtype(to_scalar_type(entry.dtype)));
  const size_t nbytes = entry.end - entry.begin;
  if (static_cast<size_t>(tensor.nbytes()) != nbytes) {
    fail(file.path() + ": tensor \"" + name + "\": " + std::to_string(nbytes) + " bytes do not fill shape " +
         shape_str(tensor));
  }
  if (nbytes > 0) std::memcpy(tensor.data_ptr(), file.data(entry), nbytes);
  return tensor;
}

TensorMap load_safetensors(const std::string& path, Metadata* metadata) {
  auto file = safetensors::MappedFile::open(path);
  TensorMap tensors;
  for (const auto& entry : file->header().entries) tensors.emplace(entry.name, read_tensor(*file, entry.name));
  if (metadata) *metadata = file->header().metadata;
  return tensors;
}

void save_safetensors(const std::string& path, const TensorMap& tensors, const Metadata& metadata) {
  std::vector<at::Tensor> host;  // keeps the CPU copies alive until written
  std::vector<safetensors::RawTensor> raw;
  host.reserve(tensors.size());
  raw.reserve(tensors.size());
  for (const auto& [name, tensor] : tensors) {
    const std::string where = path + ": tensor \"" + name + "\"";
    if (!tensor.defined()) fail(where + ": undefined tensor");
    if (tensor.layout() != at::kStrided) fail(where + ": only dense (strided) tensors can be saved");
    auto dtype = to_dtype(tensor.scalar_type());
    if (!dtype) fail(where + ": dtype " + std::string(c10::toString(tensor.scalar_type())) + " has no safetensors equivalent");
    host.push_back(tensor.detach().to(at::kCPU).contiguous());
    const auto& t = host.back();
    raw.push_back({name, *dtype, t.sizes().vec(), t.data_ptr(), static_cast<size_t>(t.nbytes())});
  }
  safetensors::write(path, raw, metadata);
}

at::Tensor load_tensor_checked(const std::string& path, const std::string& name,
                               const std::vector<int64_t>& expected, const std::string& layout) {
  auto file = safetensors::MappedFile::open(path);
  auto tensor = read_tensor(*file, name);
  check_shape(tensor, expected, path + ": tensor \"" + name + "\"", layout);
  return tensor;
}

}  // namespace flat
