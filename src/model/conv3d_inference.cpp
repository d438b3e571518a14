#include "flat/model/conv3d_inference.h"

#include <algorithm>
#include <cstdint>
#include <functional>
#include <limits>
#include <map>
#include <mutex>
#include <optional>
#include <sstream>
#include <vector>

#include <spdlog/spdlog.h>
#include <torch/torch.h>

#include "flat/core/error.h"
#include "flat/core/shape.h"

#if FLAT_WITH_CUTLASS
#include <ATen/cuda/CUDAContext.h>
#include <ATen/cuda/CUDAEvent.h>
#include <c10/cuda/CUDAGuard.h>

#include "model/cuda_sm90/conv3d_sm90_kernel.h"
#endif

namespace flat::model {
namespace {

// Diagnostics for tests (what ran, not what may run): per thread.
thread_local std::string g_last_path = "cudnn";

at::Tensor conv3d_aten(const at::Tensor& x, const at::Tensor& weight, const at::Tensor& bias,
                       std::array<int64_t, 3> padding, const at::Tensor& residual) {
  at::Tensor y = at::conv3d(x, weight, bias, {1, 1, 1}, {padding[0], padding[1], padding[2]});
  if (!residual.defined()) return y;
  if (at::GradMode::is_enabled() && (y.requires_grad() || residual.requires_grad())) return y + residual;
  return y.add_(residual);
}

#if FLAT_WITH_CUTLASS
constexpr int kCudnn = -1;

struct Timed {
  std::vector<std::pair<std::string, double>> ms;  // candidate name, ms per run
  int choice = kCudnn;
};

// The per-shape timing results: a cache of measurements (each problem shape on
// each device timed once, whoever asks), not a choice; guarded by g_mutex.
std::mutex g_mutex;
std::map<std::string, Timed> g_timed;  // by problem key

bool fits_int(const at::Tensor& t) { return !t.defined() || t.numel() < std::numeric_limits<int>::max(); }

bool is_sm90(int device) {
  const cudaDeviceProp* p = at::cuda::getDeviceProperties(device);
  return p->major == 9 && p->minor == 0;  // the kernels are sm_90a code
}

// The CUTLASS problem for these tensors, or nullopt when the fast path does
// not apply (then cuDNN runs, as before this path existed).
std::optional<cuda::Conv3dProblem> problem_for(const at::Tensor& x, const at::Tensor& weight, const at::Tensor& bias,
                                               std::array<int64_t, 3> padding, const at::Tensor& residual) {
  if (!x.is_cuda() || x.dim() != 5 || weight.dim() != 5) return std::nullopt;
  const auto bf16 = at::kBFloat16;
  if (x.scalar_type() != bf16 || weight.scalar_type() != bf16 || (bias.defined() && bias.scalar_type() != bf16) ||
      (residual.defined() && residual.scalar_type() != bf16)) {
    return std::nullopt;
  }
  if (at::GradMode::is_enabled() && (x.requires_grad() || weight.requires_grad() ||
                                     (bias.defined() && bias.requires_grad()) ||
                                     (residual.defined() && residual.requires_grad()))) {
    return std::nullopt;
  }
  // Everything on x's GPU, bias of K values, nothing empty; TMA needs 16-byte
  // aligned base pointers (views with odd offsets go to cuDNN).
  const auto on_x = [&](const at::Tensor& t) { return !t.defined() || t.device() == x.device(); };
  const auto aligned = [](const at::Tensor& t) {
    return !t.defined() || reinterpret_cast<uintptr_t>(t.data_ptr()) % 16 == 0;
  };
  if (!on_x(weight) || !on_x(bias) || !on_x(residual) || x.numel() == 0 || weight.numel() == 0) return std::nullopt;
  if (bias.defined() && (bias.dim() != 1 || bias.numel() != weight.size(0))) return std::nullopt;
  if (!aligned(x) || !aligned(weight) || !aligned(bias) || !aligned(residual)) return std::nullopt;
  const auto cl = at::MemoryFormat::ChannelsLast3d;
  if (!x.is_contiguous(cl) || !weight.is_contiguous(cl) || (bias.defined() && !bias.is_contiguous())) {
    return std::nullopt;
  }
  if (!fits_int(x) || !fits_int(weight) || !is_sm90(x.get_device())) return std::nullopt;
  cuda::Conv3dProblem p;
  p.n = int(x.size(0)), p.c = int(x.size(1)), p.d = int(x.size(2)), p.h = int(x.size(3)), p.w = int(x.size(4));
  p.k = int(weight.size(0)), p.t = int(weight.size(2)), p.r = int(weight.size(3)), p.s = int(weight.size(4));
  p.pad_d = int(padding[0]), p.pad_h = int(padding[1]), p.pad_w = int(padding[2]);
  if (weight.size(1) != x.size(1) || p.out_d() < 1 || p.out_h() < 1 || p.out_w() < 1) return std::nullopt;
  if (int64_t(p.n) * p.out_d() * p.out_h() * p.out_w() * p.k >= std::numeric_limits<int>::max()) return std::nullopt;
  if (residual.defined()) {
    const std::vector<int64_t> out{p.n, p.k, p.out_d(), p.out_h(), p.out_w()};
    if (residual.sizes() != at::IntArrayRef(out) || !residual.is_contiguous(cl)) return std::nullopt;
  }
  return p;
}

std::string key_of(const cuda::Conv3dProblem& p, bool bias, bool residual) {
  std::ostringstream s;
  s << "x(" << p.n << "," << p.c << "," << p.d << "," << p.h << "," << p.w << ") w(" << p.k << "," << p.c << ","
    << p.t << "," << p.r << "," << p.s << ") pad(" << p.pad_d << "," << p.pad_h << "," << p.pad_w << ")"
    << (bias ? "" : " no-bias") << (residual ? " +residual" : "");
  return s.str();
}

void run_cutlass(int config, const cuda::Conv3dProblem& p, const at::Tensor& x, const at::Tensor& weight,
                 const at::Tensor& bias, const at::Tensor& residual, at::Tensor& out) {
  const size_t bytes = cuda::conv3d_sm90_workspace_bytes(config, p);
  at::Tensor workspace = bytes > 0 ? at::empty({int64_t(bytes)}, x.options().dtype(at::kByte)) : at::Tensor();
  const bool ok = cuda::conv3d_sm90_run(config, p, x.data_ptr(), weight.data_ptr(),
                                        bias.defined() ? bias.data_ptr() : nullptr,
                                        residual.defined() ? residual.data_ptr() : nullptr, out.data_ptr(),
                                        bytes > 0 ? workspace.data_ptr() : nullptr,
                                        at::cuda::getCurrentCUDAStream());
  FLAT_CHECK(ok, std::string("conv3d: the CUTLASS kernel ") + cuda::conv3d_sm90_config_name(config) +
                     " refused or failed on " + key_of(p, bias.defined(), residual.defined()) +
                     " (CUDA: " + cudaGetErrorString(cudaGetLastError()) + ")");
}

// Times every candidate on this problem (one warm-up, then the mean of two
// runs) and returns the fastest; the outputs of the timing runs are discarded.
Timed time_candidates(const cuda::Conv3dProblem& p, const at::Tensor& x, const at::Tensor& weight,
                      const at::Tensor& bias, std::array<int64_t, 3> padding, const at::Tensor& residual,
                      at::Tensor& out) {
  Timed timed;
  auto time_ms = [](const std::function<void()>& fn) {
    fn();
    at::cuda::CUDAEvent start(cudaEventDefault), stop(cudaEventDefault);
    const auto stream = at::cuda::getCurrentCUDAStream();
    start.record(stream);
    for (int i = 0; i < 2; ++i) fn();
    stop.record(stream);
    stop.synchronize();
    return double(start.elapsed_time(stop)) / 2.0;
  };
  double best = time_ms([&] { (void)conv3d_aten(x, weight, bias, padding, residual); });
  timed.ms.emplace_back("cudnn", best);
  for (int c = 0; c < cuda::conv3d_sm90_config_count(); ++c) {
    if (!cuda::conv3d_sm90_can_run(c, p)) continue;
    const double ms = time_ms([&] { run_cutlass(c, p, x, weight, bias, residual, out); });
    timed.ms.emplace_back(cuda::conv3d_sm90_config_name(c), ms);
    if (ms < best) best = ms, timed.choice = c;
  }
  return timed;
}

int config_by_name(const std::string& name) {
  for (int c = 0; c < cuda::conv3d_sm90_config_count(); ++c) {
    if (name == cuda::conv3d_sm90_config_name(c)) return c;
  }
  return kCudnn;
}
#endif

}  // namespace

bool cutlass_conv_compiled() {
#if FLAT_WITH_CUTLASS
  return true;
#else
  return false;
#endif
}

std::vector<std::string> conv_backends() {
  std::vector<std::string> names{"auto", "cudnn"};
#if FLAT_WITH_CUTLASS
  for (int c = 0; c < cuda::conv3d_sm90_config_count(); ++c) names.emplace_back(cuda::conv3d_sm90_config_name(c));
#endif
  return names;
}

namespace {
// "" when name is a backend of this build, else what was expected.
std::string conv_backend_expected(const std::string& name) {
  const auto names = conv_backends();
  if (std::find(names.begin(), names.end(), name) != names.end()) return "";
  std::string list;
  for (const auto& n : names) list += (list.empty() ? "" : ", ") + n;
  return "one of {" + list + "}" +
         (cutlass_conv_compiled() ? std::string(" (auto, cudnn or a CUTLASS tile configuration)")
                                  : std::string(" (this build has no CUTLASS kernels: FLAT_WITH_CUTLASS=OFF)"));
}
}  // namespace

void check_conv_backend(const std::string& name) {
  const std::string expected = conv_backend_expected(name);
  FLAT_CHECK(expected.empty(), "conv3d: unknown conv backend '" + name + "': expected " + expected);
}

config::Check conv_backend_check() {
  config::Check c;
  c.text = conv_backend_expected;
  return c;
}

std::string cutlass_conv_report() {
  std::ostringstream s;
#if FLAT_WITH_CUTLASS
  const std::lock_guard<std::mutex> lock(g_mutex);
  for (const auto& [key, timed] : g_timed) {
    s << key << ":";
    for (const auto& [name, ms] : timed.ms) s << " " << name << " " << ms << " ms;";
    s << " -> " << (timed.choice == kCudnn ? "cudnn" : cuda::conv3d_sm90_config_name(timed.choice)) << "\n";
  }
#endif
  return s.str();
}

at::Tensor conv3d_inference(const at::Tensor& x, const at::Tensor& weight, const at::Tensor& bias,
                            std::array<int64_t, 3> padding, const at::Tensor& residual, const std::string& backend) {
#if FLAT_WITH_CUTLASS
  const bool timed = backend == "auto";
  const int forced = timed ? kCudnn : config_by_name(backend);  // cudnn: kCudnn
  if (!timed && forced == kCudnn && backend != "cudnn") check_conv_backend(backend);  // throws
  const auto p = (timed || forced != kCudnn) ? problem_for(x, weight, bias, padding, residual) : std::nullopt;
  if (p) {
    const c10::cuda::CUDAGuard guard(x.device());
    at::Tensor out = at::empty({p->n, p->k, p->out_d(), p->out_h(), p->out_w()},
                               x.options().memory_format(at::MemoryFormat::ChannelsLast3d));
    int choice = kCudnn;
    if (!timed) {
      choice = cuda::conv3d_sm90_can_run(forced, *p) ? forced : kCudnn;
    } else {
      const std::lock_guard<std::mutex> lock(g_mutex);
      const std::string key = key_of(*p, bias.defined(), residual.defined()) + " dev" + std::to_string(x.get_device());
      auto it = g_timed.find(key);
      if (it == g_timed.end()) {
        it = g_timed.emplace(key, time_candidates(*p, x, weight, bias, padding, residual, out)).first;
        spdlog::debug("conv3d {}: {}", key, it->second.choice == kCudnn
                                                ? "cudnn"
                                                : cuda::conv3d_sm90_config_name(it->second.choice));
      }
      choice = it->second.choice;
    }
    if (choice != kCudnn) {
      run_cutlass(choice, *p, x, weight, bias, residual, out);
      g_last_path = cuda::conv3d_sm90_config_name(choice);
      return out;
    }
  }
#else
  if (backend != "auto" && backend != "cudnn") check_conv_backend(backend);  // throws
#endif
  g_last_path = "cudnn";
  return conv3d_aten(x, weight, bias, padding, residual);
}

std::string conv3d_inference_last_path() { return g_last_path; }

}  // namespace flat::model
