// safetensors <-> at::Tensor. Every dtype of the format that libtorch has maps
// to it (U16/U32/U64 to libtorch's unsigned types; F8 to Float8_e4m3fn/e5m2).
#pragma once
#include <map>
#include <string>
#include <vector>

#include <ATen/ATen.h>

#include "flat/core/safetensors.h"

namespace flat {

using TensorMap = std::map<std::string, at::Tensor>;
using Metadata = std::map<std::string, std::string>;

// Loads every tensor (owned CPU copies). Throws flat::Error naming the file.
TensorMap load_safetensors(const std::string& path, Metadata* metadata = nullptr);

// One tensor out of an open file (owned CPU copy); throws naming file and tensor.
at::Tensor read_tensor(const safetensors::MappedFile& file, const std::string& name);

// Writes CPU or CUDA tensors (copied to contiguous CPU) atomically.
void save_safetensors(const std::string& path, const TensorMap& tensors, const Metadata& metadata = {});

// Loads `name` and checks its shape against `expected` (-1 = any); errors name file, tensor, shapes.
at::Tensor load_tensor_checked(const std::string& path, const std::string& name,
                               const std::vector<int64_t>& expected, const std::string& layout);

}  // namespace flat
