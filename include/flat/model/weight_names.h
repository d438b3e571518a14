// Checkpoint key names of the Wan 2.1 VAE. Our modules use the ORIGINAL names
// (Wan2.1_VAE.pth); diffusers' AutoencoderKLWan renames them (../shared/docs/wan_vae.md,
// Checkpoint key names). Keys outside the VAE (e.g. the scene decoder's
// "adapter." and "heads.") are the same in both namings.
#pragma once
#include <string>
#include <vector>

#include "flat/core/tensor_io.h"

namespace flat::model {

enum class WeightNaming { wan, diffusers };
const char* naming_name(WeightNaming naming);

// "decoder.upsamples.4.residual.2.weight" -> "decoder.up_blocks.1.resnets.0.conv1.weight".
std::string wan_to_diffusers(const std::string& key);
// The inverse; keys that are not diffusers VAE keys come back unchanged.
std::string diffusers_to_wan(const std::string& key);

// diffusers when any key has a diffusers-only part (quant_conv, up_blocks,
// down_blocks, mid_block, conv_in, conv_out, norm_out); wan otherwise.
WeightNaming detect_naming(const std::vector<std::string>& keys);
WeightNaming detect_naming(const TensorMap& tensors);

// All keys renamed to the wan naming (a no-op for wan files). Throws flat::Error
// naming `label` if two keys map to the same name.
TensorMap to_wan_naming(const TensorMap& tensors, WeightNaming from, const std::string& label);
TensorMap to_naming(const TensorMap& wan_tensors, WeightNaming to);

}  // namespace flat::model
