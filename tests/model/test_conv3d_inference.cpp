// conv3d_inference: every CUTLASS configuration against an fp32 reference conv
// of the same bf16 inputs, on the decoder's kinds of conv (3x3x3 causal with
// pre-padded time, (1,3,3) per frame, the sub-pixel (1,2,2), 1x1x1 shortcut),
// with and without the fused residual, on sizes that do not divide the tiles.
// The CUDA cases skip without an sm_90 GPU; the CPU case checks the fallback.
#include "flat/model/conv3d_inference.h"
#include "flat/core/shape.h"
#include "test_support.h"

#if FLAT_WITH_CUDA
#include <ATen/cuda/CUDAContext.h>
#endif

using namespace flat::model;

namespace {

struct Case {
  int64_t n, c, d, h, w, k, t, r, s;
  std::array<int64_t, 3> pad;
};

// The input channels a configuration takes per step: the last number of its name.
int64_t tile_k(const std::string& name) { return std::stoll(name.substr(name.rfind('x') + 1)); }

bool sm90() {
#if FLAT_WITH_CUDA
  if (!flat::test::cuda_available()) return false;
  const auto* p = at::cuda::getCurrentDeviceProperties();
  return p->major == 9 && p->minor == 0;
#else
  return false;
#endif
}

}  // namespace

TEST_CASE("conv3d_inference on the CPU is conv3d + residual", "[model]") {
  torch::manual_seed(3);
  auto x = torch::randn({1, 8, 4, 5, 6});
  auto w = torch::randn({16, 8, 3, 3, 3});
  auto b = torch::randn({16});
  auto res = torch::randn({1, 16, 2, 5, 6});
  auto ref = at::conv3d(x, w, b, {1, 1, 1}, {0, 1, 1}) + res;
  CHECK(flat::test::rel_error(conv3d_inference(x, w, b, {0, 1, 1}, res), ref) < 1e-6);
  // Every backend of this build gives the same result on the CPU (cuDNN's
  // place is ATen's there); unknown names throw, naming the valid ones.
  for (const std::string& backend : conv_backends()) {
    INFO("backend " << backend);
    CHECK(flat::test::rel_error(conv3d_inference(x, w, b, {0, 1, 1}, res, backend), ref) < 1e-6);
    CHECK(conv3d_inference_last_path() == "cudnn");
  }
  CHECK(conv_backends().front() == "auto");
  CHECK(conv_backends().size() == (cutlass_conv_compiled() ? 8u : 2u));  // auto, cudnn, six tile configurations
  CHECK_THROWS_WITH(conv3d_inference(x, w, b, {0, 1, 1}, res, "64x64x64"),
                    FLAT_CONTAINS("unknown conv backend '64x64x64'"));
  CHECK_THROWS_WITH(check_conv_backend(""), FLAT_CONTAINS("one of {auto, cudnn"));
}

TEST_CASE("CUTLASS conv3d equals an fp32 conv for every configuration", "[model][cuda]") {
  FLAT_REQUIRE_CUDA();
  if (!cutlass_conv_compiled()) FLAT_SKIP("built without CUTLASS");
  if (!sm90()) FLAT_SKIP("the CUTLASS convs are sm_90 code");
  torch::manual_seed(5);
  torch::NoGradGuard no_grad;
  const auto cl = at::MemoryFormat::ChannelsLast3d;
  const std::vector<Case> cases = {
      {1, 96, 7, 19, 37, 96, 3, 3, 3, {0, 1, 1}},    // full-resolution block conv (time pre-padded)
      {2, 192, 4, 9, 13, 96, 3, 3, 3, {0, 1, 1}},    // 192 -> 96, batch 2
      {1, 192, 5, 11, 17, 384, 3, 3, 3, {0, 1, 1}},  // two N tiles of 192 / three of 128
      {1, 384, 3, 8, 10, 192, 1, 3, 3, {0, 1, 1}},   // per-frame 3x3 (Resample conv)
      {1, 384, 3, 8, 10, 768, 1, 2, 2, {0, 1, 1}},   // sub-pixel upsample conv (4 x 192 outputs)
      {1, 192, 3, 8, 10, 384, 1, 1, 1, {0, 0, 0}},   // 1x1x1 shortcut
      {1, 64, 4, 6, 6, 16, 3, 3, 3, {0, 1, 1}},      // narrow output (one partial N tile)
  };
  for (const Case& k : cases) {
    auto x = torch::randn({k.n, k.c, k.d, k.h, k.w}, torch::kCUDA).to(torch::kBFloat16).contiguous(cl);
    auto w = (torch::randn({k.k, k.c, k.t, k.r, k.s}, torch::kCUDA) / std::sqrt(double(k.c * k.t * k.r * k.s)))
                 .to(torch::kBFloat16)
                 .contiguous(cl);
    auto b = torch::randn({k.k}, torch::kCUDA).to(torch::kBFloat16);
    auto ref0 = at::conv3d(x.to(torch::kFloat), w.to(torch::kFloat), b.to(torch::kFloat), {1, 1, 1}, k.pad);
    auto res = torch::randn(ref0.sizes(), torch::kCUDA).to(torch::kBFloat16).contiguous(cl);
    auto ref1 = ref0 + res.to(torch::kFloat);
    int cutlass_runs = 0;
    for (const std::string config :
         {"128x96x32", "256x96x32", "128x96x64", "256x96x64", "128x128x64", "128x192x64", "auto"}) {
      for (bool with_res : {false, true}) {
        auto out = conv3d_inference(x, w, b, k.pad, with_res ? res : at::Tensor(), config);
        const std::string path = conv3d_inference_last_path();
        INFO("x " << flat::shape_str(x) << " w " << flat::shape_str(w) << " config '" << config << "' residual "
                  << with_res << " ran " << path);
        // A forced configuration runs exactly where its K step divides the
        // input channels (every output count here is a multiple of 8).
        if (config != "auto") CHECK(path == (k.c % tile_k(config) == 0 ? config : std::string("cudnn")));
        cutlass_runs += path != "cudnn" ? 1 : 0;
        REQUIRE(out.sizes() == ref0.sizes());
        CHECK(out.is_contiguous(cl));
        // bf16 output: a few ulp of the output's scale; a wrong layout or
        // tap is O(1).
        CHECK(flat::test::rel_error(out.to(torch::kFloat), with_res ? ref1 : ref0) < 1e-2);
      }
    }
    CHECK(cutlass_runs >= 4);  // at least the two 32-channel-step configurations, both forms
  }
  // Without a bias (the epilogue's bias pointer is null).
  {
    auto x = torch::randn({1, 96, 4, 6, 9}, torch::kCUDA).to(torch::kBFloat16).contiguous(cl);
    auto w = (torch::randn({96, 96, 3, 3, 3}, torch::kCUDA) * 0.03).to(torch::kBFloat16).contiguous(cl);
    auto out = conv3d_inference(x, w, at::Tensor(), {0, 1, 1}, {}, "128x96x32");
    CHECK(conv3d_inference_last_path() == "128x96x32");
    // cudnn: never a CUTLASS kernel, same result.
    auto out_cudnn = conv3d_inference(x, w, at::Tensor(), {0, 1, 1}, {}, "cudnn");
    CHECK(conv3d_inference_last_path() == "cudnn");
    CHECK(flat::test::rel_error(out_cudnn.to(torch::kFloat), out.to(torch::kFloat)) < 1e-2);
    auto ref = at::conv3d(x.to(torch::kFloat), w.to(torch::kFloat), {}, {1, 1, 1}, {0, 1, 1});
    CHECK(flat::test::rel_error(out.to(torch::kFloat), ref) < 1e-2);
  }
  // The per-shape timing recorded a choice for every auto-timed shape.
  const std::string report = cutlass_conv_report();
  CHECK(report.find("-> ") != std::string::npos);
}

TEST_CASE("CUTLASS conv3d is skipped where it does not apply", "[model][cuda]") {
  FLAT_REQUIRE_CUDA();
  if (!cutlass_conv_compiled()) FLAT_SKIP("built without CUTLASS");
  torch::manual_seed(6);
  torch::NoGradGuard no_grad;
  const auto cl = at::MemoryFormat::ChannelsLast3d;
  // 12 output channels (not a multiple of 8): cuDNN, same result.
  auto x = torch::randn({1, 96, 4, 6, 7}, torch::kCUDA).to(torch::kBFloat16).contiguous(cl);
  auto w = (torch::randn({12, 96, 3, 3, 3}, torch::kCUDA) * 0.03).to(torch::kBFloat16).contiguous(cl);
  auto b = torch::randn({12}, torch::kCUDA).to(torch::kBFloat16);
  const std::string forced = "128x96x32";
  auto ref = at::conv3d(x.to(torch::kFloat), w.to(torch::kFloat), b.to(torch::kFloat), {1, 1, 1}, {0, 1, 1});
  CHECK(flat::test::rel_error(conv3d_inference(x, w, b, {0, 1, 1}, {}, forced).to(torch::kFloat), ref) < 1e-2);
  CHECK(conv3d_inference_last_path() == "cudnn");
  // A bias of the wrong length, or an input view off 16-byte alignment: cuDNN
  // (which names the bad bias itself), never the CUTLASS kernel.
  auto w16 = (torch::randn({16, 96, 3, 3, 3}, torch::kCUDA) * 0.03).to(torch::kBFloat16).contiguous(cl);
  CHECK_THROWS(conv3d_inference(x, w16, b, {0, 1, 1}, {}, forced));
  CHECK(conv3d_inference_last_path() == "cudnn");
  auto buffer = torch::zeros({x.numel() + 1}, x.options());
  auto shifted = buffer.narrow(0, 1, x.numel()).view({1, 4, 6, 7, 96}).permute({0, 4, 1, 2, 3});
  shifted.copy_(x);
  REQUIRE(shifted.is_contiguous(cl));
  auto ref16 = at::conv3d(x.to(torch::kFloat), w16.to(torch::kFloat), {}, {1, 1, 1}, {0, 1, 1});
  CHECK(flat::test::rel_error(conv3d_inference(shifted, w16, {}, {0, 1, 1}, {}, forced).to(torch::kFloat), ref16) <
        1e-2);
  CHECK(conv3d_inference_last_path() == "cudnn");
  // Under autograd the differentiable cuDNN path runs: gradients reach x.
  auto xg = x.detach().clone().requires_grad_(true);
  {
    torch::AutoGradMode grad(true);
    conv3d_inference(xg, w, b, {0, 1, 1}, {}, forced).to(torch::kFloat).sum().backward();
  }
  CHECK(xg.grad().defined());
  CHECK(conv3d_inference_last_path() == "cudnn");
}
