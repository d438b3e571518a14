// Which implementation runs some of the model's operations (YAML: the
// `kernels` section of the scene decoder's config, pipeline.model.kernels in
// flat_train). They choose speed, never the result: every choice computes the
// same function up to float rounding (tests compare them).
//
// Each module keeps the choices it was built with (a member set by its
// constructor), so a forward recomputed by activation checkpointing, or a
// backward on an autograd thread, runs the same kernels as the forward;
// nothing here is process-wide.
#pragma once
#include <string>

#include "flat/core/config.h"
#include "flat/model/conv3d_inference.h"

namespace flat::model {

struct KernelChoices {
  // CUDA, without autograd: silu(rms_norm(x)) as one fused kernel that also
  // writes the next conv's causal padding; false: ATen ops.
  bool fused_norm = true;
  // The x2 upsampling convs as one sub-pixel conv on the low-resolution input
  // (4/9 of the work); false: nearest x2 then the 3x3 conv, the reference form.
  bool subpixel_upsample = true;
  // bf16 channels-last convs on an sm_90 GPU without autograd: "auto" (the
  // fastest of cuDNN and the CUTLASS kernels, timed once per problem shape),
  // "cudnn", or one CUTLASS tile configuration by name (e.g. "128x192x64").
  std::string conv_backend = "auto";

  template <class V>
  void visit(V& v) {
    v.field("fused_norm", fused_norm, "CUDA inference: fused RMS_norm+SiLU kernel; false: ATen ops (same result)");
    v.field("subpixel_upsample", subpixel_upsample,
            "x2 upsampling conv as one sub-pixel conv; false: nearest x2 then the 3x3 conv (same result)");
    v.field("conv_backend", conv_backend, conv_backend_check(),
            "bf16 convs on sm_90: auto (fastest per shape) | cudnn | a CUTLASS tile configuration, e.g. 128x192x64");
  }
};

// The declared checks of k's fields, for choices built in code (YAML is
// checked when read): "<what>: 'kernels.conv_backend': expected ..., got ...".
inline void validate_kernels(const KernelChoices& k, const std::string& what) {
  KernelChoices copy = k;
  config::Validator v(config::Where{what, "kernels"});
  copy.visit(v);
}

}  // namespace flat::model
