#include "flat/model/weights.h"

#include <filesystem>
#include <sstream>

#include <spdlog/spdlog.h>
#include <torch/torch.h>

#include "flat/core/error.h"
#include "flat/core/shape.h"

namespace flat::model {
namespace {

bool has_prefix(const std::string& s, const std::vector<std::string>& prefixes) {
  for (const auto& p : prefixes) {
    if (s.compare(0, p.size(), p) == 0) return true;
  }
  return false;
}

std::string join_list(const std::vector<std::string>& items, size_t limit = 40) {
  std::ostringstream os;
  for (size_t i = 0; i < items.size() && i < limit; ++i) os << (i ? ", " : "") << items[i];
  if (items.size() > limit) os << ", ... (" << items.size() - limit << " more)";
  return os.str();
}

// The dotted prefix ("vae.", "model.vae.") every file key carries and no module
// parameter starts with: how other tools save a sub-model.
std::string common_foreign_prefix(const TensorMap& tensors, const torch::nn::Module& module) {
  if (tensors.empty()) return "";
  const auto params = module.named_parameters(/*recurse=*/true);
  std::string prefix;
  for (;;) {
    std::string first;
    for (const auto& [key, value] : tensors) {
      if (key.compare(0, prefix.size(), prefix) != 0) return prefix;
      const auto dot = key.find('.', prefix.size());
      if (dot == std::string::npos) return prefix;
      const std::string segment = key.substr(0, dot + 1);
      if (first.empty()) first = segment;
      if (segment != first) return prefix;
    }
    for (const auto& item : params)
      if (item.key().compare(0, first.size() - prefix.size(), first.substr(prefix.size())) == 0) return prefix;
    prefix = first;
  }
}

TensorMap without_prefix(const TensorMap& tensors, const std::string& prefix, const std::string& label) {
  TensorMap out;
  for (const auto& [key, value] : tensors) {
    if (key.compare(0, prefix.size(), prefix) != 0)
      fail(label + ": key '" + key + "' does not start with the prefix '" + prefix + "' to strip");
    out.emplace(key.substr(prefix.size()), value);
  }
  return out;
}

}  // namespace

std::string resolve_weights_file(const std::string& path) {
  namespace fs = std::filesystem;
  std::error_code ec;
  if (!fs::is_directory(path, ec)) return path;
  for (const char* name : {"diffusion_pytorch_model.safetensors", "model.safetensors"})
    if (fs::exists(fs::path(path) / name, ec)) return (fs::path(path) / name).string();
  std::vector<std::string> found;
  for (const auto& e : fs::directory_iterator(path, ec))
    if (e.path().extension() == ".safetensors") found.push_back(e.path().string());
  if (found.size() == 1) return found.front();
  if (found.empty()) fail(path + ": a folder without a .safetensors file (expected diffusion_pytorch_model.safetensors)");
  fail(path + ": a folder with " + std::to_string(found.size()) +
       " .safetensors files and no diffusion_pytorch_model.safetensors; name the file");
}

std::string LoadReport::summary() const {
  std::ostringstream os;
  os << file << " (" << naming_name(naming) << " naming): " << loaded.size() << " tensors loaded";
  if (!initialised.empty()) os << ", " << initialised.size() << " kept initialised";
  if (!skipped.empty()) os << ", " << skipped.size() << " file tensors not used";
  return os.str();
}

LoadReport load_state(torch::nn::Module& module, const TensorMap& tensors, const LoadSpec& spec,
                      const std::string& label) {
  LoadReport report;
  report.file = label;
  std::string strip = spec.strip_prefix;
  if (strip.empty() && spec.file_prefix.empty() && spec.take.empty()) {
    strip = common_foreign_prefix(tensors, module);
    if (!strip.empty())
      spdlog::info("weights: {}: stripped the prefix '{}' that all {} keys carry", label, strip, tensors.size());
  }
  const TensorMap stripped = strip.empty() ? TensorMap{} : without_prefix(tensors, strip, label);
  const TensorMap& source = strip.empty() ? tensors : stripped;
  report.naming = detect_naming(source);
  TensorMap renamed = to_wan_naming(source, report.naming, label);

  TensorMap wanted;
  for (auto& [key, value] : renamed) {
    std::string name = key;
    if (!spec.file_prefix.empty()) {
      if (name.compare(0, spec.file_prefix.size(), spec.file_prefix) != 0) {
        report.skipped.push_back(key);
        continue;
      }
      name = name.substr(spec.file_prefix.size());
    }
    if (!spec.take.empty() && !has_prefix(name, spec.take)) {
      report.skipped.push_back(key);
      continue;
    }
    wanted.emplace(name, value);
  }

  std::vector<std::string> missing, wrong_shape, unexpected;
  auto params = module.named_parameters(/*recurse=*/true);
  std::vector<std::pair<at::Tensor, at::Tensor>> copies;
  for (const auto& item : params) {
    const std::string& name = item.key();
    auto it = wanted.find(name);
    if (it == wanted.end()) {
      if (has_prefix(name, spec.keep_initialised)) {
        report.initialised.push_back(name);
      } else {
        missing.push_back(name + " " + shape_str(item.value()));
      }
      continue;
    }
    if (it->second.sizes() != item.value().sizes()) {
      wrong_shape.push_back(name + ": file " + shape_str(it->second) + ", model " + shape_str(item.value()));
    } else {
      copies.emplace_back(item.value(), it->second);
      report.loaded.push_back(name);
    }
  }
  for (const auto& [name, value] : wanted) {
    if (!params.contains(name)) unexpected.push_back(name + " " + shape_str(value));
  }
  if (!missing.empty() || !unexpected.empty() || !wrong_shape.empty()) {
    std::ostringstream os;
    os << label << ": weights do not match the model (" << naming_name(report.naming) << " naming; "
       << copies.size() << " tensors match).";
    if (copies.empty() && !unexpected.empty())
      os << "\n  hint: no key matches; if the file's keys carry a prefix, pass it (--vae-prefix PREFIX.)";
    if (!missing.empty()) os << "\n  missing (" << missing.size() << "): " << join_list(missing);
    if (!unexpected.empty()) os << "\n  unexpected (" << unexpected.size() << "): " << join_list(unexpected);
    if (!wrong_shape.empty()) os << "\n  wrong shape (" << wrong_shape.size() << "): " << join_list(wrong_shape);
    fail(os.str());
  }
  torch::NoGradGuard no_grad;
  for (auto& [param, value] : copies) param.copy_(value);
  return report;
}

LoadReport load_weights(torch::nn::Module& module, const std::string& path, const LoadSpec& spec) {
  Metadata metadata;
  const std::string file = resolve_weights_file(path);
  if (file != path) spdlog::info("weights: {} is a folder; reading {}", path, file);
  TensorMap tensors = load_safetensors(file, &metadata);
  // Weights are floating point; integer tensors mean the wrong file (a tokenizer, an index).
  for (const auto& [key, value] : tensors)
    if (!value.is_floating_point())
      fail(file + ": tensor '" + key + "' has dtype " + std::string(c10::toString(value.scalar_type())) +
           "; weights must be floating point");
  // NaN weights would turn every output into NaN with exit 0.
  for (const auto& [key, value] : tensors) check_finite(value, file + ": tensor '" + key + "'");
  LoadReport report = load_state(module, tensors, spec, file);
  spdlog::info("weights: {}", report.summary());
  return report;
}

TensorMap state_tensors(const torch::nn::Module& module, WeightNaming naming) {
  TensorMap wan;
  for (const auto& item : module.named_parameters(/*recurse=*/true)) {
    wan.emplace(item.key(), item.value().detach().to(at::kCPU).contiguous());
  }
  return to_naming(wan, naming);
}

void save_weights(const torch::nn::Module& module, const std::string& path, WeightNaming naming,
                  const Metadata& metadata) {
  Metadata meta = metadata;
  meta["format"] = "flat";
  meta["naming"] = naming_name(naming);
  save_safetensors(path, state_tensors(module, naming), meta);
}

int64_t count_parameters(const torch::nn::Module& module, const std::string& prefix) {
  int64_t n = 0;
  for (const auto& item : module.named_parameters(/*recurse=*/true)) {
    if (item.key().compare(0, prefix.size(), prefix) == 0) n += item.value().numel();
  }
  return n;
}

void to_channels_last_3d(torch::nn::Module& module) {
  torch::NoGradGuard no_grad;
  for (auto& p : module.parameters(/*recurse=*/true)) {
    if (p.dim() == 5) p.set_data(p.data().contiguous(at::MemoryFormat::ChannelsLast3d));
  }
}

}  // namespace flat::model
