// RAII bf16 autocast for one device type (training, inference, evaluation).
#pragma once
#include <ATen/ATen.h>

namespace flat {

// RAII: bf16 autocast on one device type while alive (no-op when off).
class AutocastScope {
 public:
  AutocastScope(bool enabled, at::DeviceType device);
  ~AutocastScope();
  AutocastScope(const AutocastScope&) = delete;
  AutocastScope& operator=(const AutocastScope&) = delete;

 private:
  bool enabled_;
  at::DeviceType device_;
  bool was_enabled_ = false;
  at::ScalarType was_dtype_ = at::kFloat;
};

}  // namespace flat
