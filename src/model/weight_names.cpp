#include "flat/model/weight_names.h"

#include <regex>

#include "flat/core/error.h"

namespace flat::model {
namespace {

// Key prefixes renamed between the two namings: (original, diffusers).
using Renames = std::vector<std::pair<std::string, std::string>>;

// Residual-block internals.
const Renames kResidualParts = {{"residual.0.gamma", "norm1.gamma"}, {"residual.2.", "conv1."},
                                {"residual.3.gamma", "norm2.gamma"}, {"residual.6.", "conv2."},
                                {"shortcut.", "conv_shortcut."}};
// The quant convs around the latent.
const Renames kQuantConvs = {{"conv1.", "quant_conv."}, {"conv2.", "post_quant_conv."}};
// Inside "encoder." or "decoder.": conv1 / head / the middle attention, and the middle residual blocks.
const Renames kCommonParts = {{"conv1.", "conv_in."},
                              {"head.0.gamma", "norm_out.gamma"},
                              {"head.2.", "conv_out."},
                              {"middle.1.", "mid_block.attentions.0."}};
const Renames kMiddleResnets = {{"middle.0.", "mid_block.resnets.0."}, {"middle.2.", "mid_block.resnets.1."}};

bool starts_with(const std::string& s, const std::string& p) { return s.compare(0, p.size(), p) == 0; }

// The prefix of `key` that `renames` lists in the naming it comes from, and
// what it becomes in the other; {"", ""} when none does.
std::pair<std::string, std::string> matching_rename(const std::string& key, const Renames& renames,
                                                    bool to_diffusers) {
  for (const auto& [wan, diff] : renames) {
    const std::string& from = to_diffusers ? wan : diff;
    if (starts_with(key, from)) return {from, to_diffusers ? diff : wan};
  }
  return {};
}

// Renames a residual block's part ("residual.2.weight") in either direction.
std::string rename_residual_part(const std::string& rest, bool to_diffusers) {
  const auto [from, to] = matching_rename(rest, kResidualParts, to_diffusers);
  return from.empty() ? rest : to + rest.substr(from.size());
}

// The renames both directions share: the quant convs, and inside "encoder."
// or "decoder." conv1 / head / middle. "" for any other key (the down / up
// blocks, or not a VAE key).
std::string rename_outside_blocks(const std::string& key, bool to_diffusers) {
  if (const auto [from, to] = matching_rename(key, kQuantConvs, to_diffusers); !from.empty())
    return to + key.substr(from.size());
  for (const std::string side : {"encoder.", "decoder."}) {
    if (!starts_with(key, side)) continue;
    const std::string rest = key.substr(side.size());
    if (const auto [from, to] = matching_rename(rest, kCommonParts, to_diffusers); !from.empty())
      return side + to + rest.substr(from.size());
    if (const auto [from, to] = matching_rename(rest, kMiddleResnets, to_diffusers); !from.empty())
      return side + to + rename_residual_part(rest.substr(from.size()), to_diffusers);
  }
  return "";
}

}  // namespace

const char* naming_name(WeightNaming naming) { return naming == WeightNaming::wan ? "wan" : "diffusers"; }

std::string wan_to_diffusers(const std::string& key) {
  if (std::string renamed = rename_outside_blocks(key, true); !renamed.empty()) return renamed;
  std::smatch m;
  static const std::regex down(R"(^encoder\.downsamples\.(\d+)\.(.*)$)");
  static const std::regex up(R"(^decoder\.upsamples\.(\d+)\.(.*)$)");
  if (std::regex_match(key, m, down))
    return "encoder.down_blocks." + m[1].str() + "." + rename_residual_part(m[2].str(), true);
  if (std::regex_match(key, m, up)) {
    const int index = std::stoi(m[1].str());
    const int block = index / 4, r = index % 4;
    if (r == 3) return "decoder.up_blocks." + std::to_string(block) + ".upsamplers.0." + m[2].str();
    return "decoder.up_blocks." + std::to_string(block) + ".resnets." + std::to_string(r) + "." +
           rename_residual_part(m[2].str(), true);
  }
  return key;
}

std::string diffusers_to_wan(const std::string& key) {
  if (std::string renamed = rename_outside_blocks(key, false); !renamed.empty()) return renamed;
  std::smatch m;
  static const std::regex down(R"(^encoder\.down_blocks\.(\d+)\.(.*)$)");
  static const std::regex up_res(R"(^decoder\.up_blocks\.(\d+)\.resnets\.(\d+)\.(.*)$)");
  static const std::regex up_sampler(R"(^decoder\.up_blocks\.(\d+)\.upsamplers\.0\.(.*)$)");
  if (std::regex_match(key, m, down))
    return "encoder.downsamples." + m[1].str() + "." + rename_residual_part(m[2].str(), false);
  if (std::regex_match(key, m, up_res)) {
    const int index = 4 * std::stoi(m[1].str()) + std::stoi(m[2].str());
    return "decoder.upsamples." + std::to_string(index) + "." + rename_residual_part(m[3].str(), false);
  }
  if (std::regex_match(key, m, up_sampler))
    return "decoder.upsamples." + std::to_string(4 * std::stoi(m[1].str()) + 3) + "." + m[2].str();
  return key;
}

WeightNaming detect_naming(const std::vector<std::string>& keys) {
  static const std::regex diffusers_part(
      R"((^|\.)(quant_conv|post_quant_conv|up_blocks|down_blocks|mid_block|conv_in|conv_out|norm_out)\.)");
  for (const auto& k : keys) {
    if (std::regex_search(k, diffusers_part)) return WeightNaming::diffusers;
  }
  return WeightNaming::wan;
}

WeightNaming detect_naming(const TensorMap& tensors) {
  std::vector<std::string> keys;
  for (const auto& kv : tensors) keys.push_back(kv.first);
  return detect_naming(keys);
}

TensorMap to_wan_naming(const TensorMap& tensors, WeightNaming from, const std::string& label) {
  if (from == WeightNaming::wan) return tensors;
  TensorMap out;
  for (const auto& [key, value] : tensors) {
    std::string name = diffusers_to_wan(key);
    FLAT_CHECK(!out.count(name), label + ": two tensors map to the same name '" + name + "'");
    out.emplace(name, value);
  }
  return out;
}

TensorMap to_naming(const TensorMap& wan_tensors, WeightNaming to) {
  if (to == WeightNaming::wan) return wan_tensors;
  TensorMap out;
  for (const auto& [key, value] : wan_tensors) out.emplace(wan_to_diffusers(key), value);
  return out;
}

}  // namespace flat::model
