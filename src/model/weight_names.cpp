#include "flat/model/weight_names.h"

#include <regex>

#include "flat/core/error.h"

namespace flat::model {
namespace {

// Residual-block internals (original -> diffusers).
const std::vector<std::pair<std::string, std::string>> kResidualParts = {
    {"residual.0.gamma", "norm1.gamma"}, {"residual.2.", "conv1."},         {"residual.3.gamma", "norm2.gamma"},
    {"residual.6.", "conv2."},           {"shortcut.", "conv_shortcut."}};

bool starts_with(const std::string& s, const std::string& p) { return s.compare(0, p.size(), p) == 0; }

std::string replace_prefix(const std::string& s, const std::string& from, const std::string& to) {
  return to + s.substr(from.size());
}

// Renames a residual block's part ("residual.2.weight") in either direction.
std::string rename_residual_part(const std::string& rest, bool to_diffusers) {
  for (const auto& [wan, diff] : kResidualParts) {
    const std::string& from = to_diffusers ? wan : diff;
    const std::string& to = to_diffusers ? diff : wan;
    if (starts_with(rest, from)) return replace_prefix(rest, from, to);
  }
  return rest;
}

// Inside "encoder." or "decoder.": conv1 / head / middle renames.
std::string rename_common(const std::string& rest, bool to_diffusers) {
  const std::vector<std::pair<std::string, std::string>> parts = {
      {"conv1.", "conv_in."}, {"head.0.gamma", "norm_out.gamma"}, {"head.2.", "conv_out."},
      {"middle.1.", "mid_block.attentions.0."}};
  for (const auto& [wan, diff] : parts) {
    const std::string& from = to_diffusers ? wan : diff;
    const std::string& to = to_diffusers ? diff : wan;
    if (starts_with(rest, from)) return replace_prefix(rest, from, to);
  }
  const std::vector<std::pair<std::string, std::string>> resnets = {{"middle.0.", "mid_block.resnets.0."},
                                                                    {"middle.2.", "mid_block.resnets.1."}};
  for (const auto& [wan, diff] : resnets) {
    const std::string& from = to_diffusers ? wan : diff;
    const std::string& to = to_diffusers ? diff : wan;
    if (starts_with(rest, from)) return to + rename_residual_part(rest.substr(from.size()), to_diffusers);
  }
  return "";
}

}  // namespace

const char* naming_name(WeightNaming naming) { return naming == WeightNaming::wan ? "wan" : "diffusers"; }

std::string wan_to_diffusers(const std::string& key) {
  if (starts_with(key, "conv1.")) return replace_prefix(key, "conv1.", "quant_conv.");
  if (starts_with(key, "conv2.")) return replace_prefix(key, "conv2.", "post_quant_conv.");
  for (const std::string side : {"encoder.", "decoder."}) {
    if (!starts_with(key, side)) continue;
    const std::string rest = key.substr(side.size());
    std::string common = rename_common(rest, true);
    if (!common.empty()) return side + common;
    std::smatch m;
    static const std::regex down(R"(^downsamples\.(\d+)\.(.*)$)");
    static const std::regex up(R"(^upsamples\.(\d+)\.(.*)$)");
    if (side == "encoder." && std::regex_match(rest, m, down)) {
      return side + "down_blocks." + m[1].str() + "." + rename_residual_part(m[2].str(), true);
    }
    if (side == "decoder." && std::regex_match(rest, m, up)) {
      const int index = std::stoi(m[1].str());
      const int block = index / 4, r = index % 4;
      if (r == 3) return side + "up_blocks." + std::to_string(block) + ".upsamplers.0." + m[2].str();
      return side + "up_blocks." + std::to_string(block) + ".resnets." + std::to_string(r) + "." +
             rename_residual_part(m[2].str(), true);
    }
  }
  return key;
}

std::string diffusers_to_wan(const std::string& key) {
  if (starts_with(key, "quant_conv.")) return replace_prefix(key, "quant_conv.", "conv1.");
  if (starts_with(key, "post_quant_conv.")) return replace_prefix(key, "post_quant_conv.", "conv2.");
  for (const std::string side : {"encoder.", "decoder."}) {
    if (!starts_with(key, side)) continue;
    const std::string rest = key.substr(side.size());
    std::string common = rename_common(rest, false);
    if (!common.empty()) return side + common;
    std::smatch m;
    static const std::regex down(R"(^down_blocks\.(\d+)\.(.*)$)");
    static const std::regex up_res(R"(^up_blocks\.(\d+)\.resnets\.(\d+)\.(.*)$)");
    static const std::regex up_sampler(R"(^up_blocks\.(\d+)\.upsamplers\.0\.(.*)$)");
    if (side == "encoder." && std::regex_match(rest, m, down)) {
      return side + "downsamples." + m[1].str() + "." + rename_residual_part(m[2].str(), false);
    }
    if (side == "decoder." && std::regex_match(rest, m, up_res)) {
      const int index = 4 * std::stoi(m[1].str()) + std::stoi(m[2].str());
      return side + "upsamples." + std::to_string(index) + "." + rename_residual_part(m[3].str(), false);
    }
    if (side == "decoder." && std::regex_match(rest, m, up_sampler)) {
      return side + "upsamples." + std::to_string(4 * std::stoi(m[1].str()) + 3) + "." + m[2].str();
    }
  }
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
