// Losses and metrics on CUDA tensors against the same calls on the CPU
// (values and gradients). Skips without a GPU.
#include "flat/eval/image_metrics.h"
#include "flat/eval/normal_metrics.h"
#include "flat/loss/depth.h"
#include "flat/loss/lpips.h"
#include "flat/loss/normal.h"
#include "flat/loss/opacity.h"
#include "flat/loss/photometric.h"
#include "flat/loss/regularisers_2dgs.h"
#include "flat/loss/ssim.h"
#include "loss/lpips_tap_distance.h"
#include "test_support.h"

using namespace flat;

namespace {

struct Images {
  at::Tensor rgb, target, alpha, depth, target_depth, normal, target_normal, intrinsics, opacities;
};

Images make_images(int64_t V, int64_t H, int64_t W) {
  torch::manual_seed(11);
  Images m;
  m.rgb = torch::rand({V, 3, H, W}, torch::kDouble);
  m.target = (m.rgb + 0.1 * torch::randn({V, 3, H, W}, torch::kDouble)).clamp(0, 1);
  m.alpha = torch::rand({V, 1, H, W}, torch::kDouble);
  m.depth = 1.0 + torch::rand({V, 1, H, W}, torch::kDouble);
  m.target_depth = 2.0 * m.depth + 0.05 * torch::rand({V, 1, H, W}, torch::kDouble);
  m.normal = torch::nn::functional::normalize(torch::randn({V, 3, H, W}, torch::kDouble),
                                              torch::nn::functional::NormalizeFuncOptions().dim(1));
  m.target_normal = torch::nn::functional::normalize(m.normal + 0.3 * torch::randn({V, 3, H, W}, torch::kDouble),
                                                     torch::nn::functional::NormalizeFuncOptions().dim(1));
  m.intrinsics = torch::tensor({0.9, 1.2, 0.5, 0.5}, torch::kDouble).repeat({V, 1});
  m.opacities = torch::rand({500}, torch::kDouble);
  return m;
}

// Evaluates f on CPU and CUDA copies (float32) of the inputs; compares the
// value and the gradient with respect to the first input.
void compare(const char* name, const std::function<at::Tensor(const std::vector<at::Tensor>&)>& f,
             const std::vector<at::Tensor>& inputs, double tol = 1e-4) {
  std::vector<at::Tensor> grads;
  std::vector<at::Tensor> values;
  for (auto device : {at::Device(at::kCPU), at::Device(at::kCUDA)}) {
    std::vector<at::Tensor> xs;
    for (const auto& x : inputs) xs.push_back(x.to(device, at::kFloat).detach());
    xs[0].requires_grad_(true);
    auto value = f(xs).sum();
    value.backward();
    values.push_back(value.detach().cpu());
    grads.push_back(xs[0].grad().cpu());
  }
  INFO(name << ": cpu " << values[0].item<double>() << " cuda " << values[1].item<double>());
  CHECK(test::rel_error(values[1], values[0]) < tol);
  CHECK(test::rel_error(grads[1], grads[0]) < tol);
  CHECK(grads[0].abs().sum().item<double>() > 0);
}

}  // namespace

TEST_CASE("losses and metrics on CUDA equal the CPU values and gradients", "[loss][cuda]") {
  FLAT_REQUIRE_CUDA();
  auto m = make_images(3, 24, 32);
  compare("l2", [](auto& x) { return loss::l2_loss(x[0], x[1]); }, {m.rgb, m.target});
  compare("ssim", [](auto& x) { return loss::ssim(x[0], x[1]); }, {m.rgb, m.target});
  compare("disparity", [](auto& x) { return loss::disparity_loss(x[0], x[1]); },
          {loss::depth_to_disparity(m.depth), loss::depth_to_disparity(m.target_depth)});
  compare("normal", [](auto& x) { return loss::normal_loss(x[0], x[1], x[2]); },
          {m.normal, m.target_normal, m.alpha});
  compare("opacity", [](auto& x) { return loss::opacity_loss(x[0]); }, {m.opacities});
  compare("normal consistency", [](auto& x) { return loss::normal_consistency_loss(x[0], x[1], x[2], x[3]); },
          {m.normal, m.depth, m.alpha, m.intrinsics});
  compare("psnr", [](auto& x) { return eval::psnr(x[0], x[1]); }, {m.rgb, m.target});

  auto acc_cpu = eval::normal_accuracy(m.normal.to(at::kFloat), m.target_normal.to(at::kFloat));
  auto acc_gpu = eval::normal_accuracy(m.normal.to(at::kCUDA, at::kFloat), m.target_normal.to(at::kCUDA, at::kFloat));
  CHECK(acc_gpu.mean_cosine == Approx(acc_cpu.mean_cosine).epsilon(1e-5));
  CHECK(acc_gpu.mean_l1 == Approx(acc_cpu.mean_l1).epsilon(1e-5));
  CHECK(acc_gpu.valid_pixels == acc_cpu.valid_pixels);
}

TEST_CASE("LPIPS on CUDA equals the CPU value and gradient (random weights)", "[loss][cuda]") {
  FLAT_REQUIRE_CUDA();
  torch::manual_seed(3);
  loss::Lpips cpu_net;
  loss::Lpips gpu_net;
  // Same random weights on both devices.
  auto src = cpu_net->parameters();
  auto dst = gpu_net->parameters();
  REQUIRE(src.size() == dst.size());
  {
    torch::NoGradGuard guard;
    for (size_t i = 0; i < src.size(); ++i) dst[i].copy_(src[i]);
  }
  gpu_net->to(at::kCUDA);
  auto m = make_images(2, 32, 48);
  std::vector<at::Tensor> grads, values;
  for (auto* net : {&cpu_net, &gpu_net}) {
    auto device = (*net)->parameters()[0].device();
    // TF32 would loosen the CUDA convolutions far beyond fp32 rounding.
    at::globalContext().setAllowTF32CuDNN(false);
    auto a = m.rgb.to(device, at::kFloat).requires_grad_(true);
    auto b = m.target.to(device, at::kFloat);
    auto d = loss::lpips_distance(*net, a, b, {.max_size = 0, .chunk = 1});
    d.sum().backward();
    values.push_back(d.detach().cpu());
    grads.push_back(a.grad().cpu());
  }
  INFO("lpips cpu " << values[0] << " cuda " << values[1]);
  CHECK(test::rel_error(values[1], values[0]) < 1e-4);
  CHECK(test::rel_error(grads[1], grads[0]) < 1e-3);
}

TEST_CASE("LPIPS tap on CUDA (fused bf16 kernels): value and gradients equal the fp64 ATen path", "[loss][cuda]") {
  FLAT_REQUIRE_CUDA();
  torch::manual_seed(5);
  // VGG's tap widths: 2, 4, 8 and 16 lanes per pixel; 5x7 pixels per view,
  // so blocks straddle views.
  for (int64_t c : {64, 128, 256, 512}) {
    for (bool grad_b : {false, true}) {
      auto a0 = torch::relu(torch::randn({3, c, 5, 7})).to(torch::kBFloat16);
      auto b0 = torch::relu(torch::randn({3, c, 5, 7}) + 0.3 * a0.to(torch::kFloat)).to(torch::kBFloat16);
      auto w = torch::rand({1, c, 1, 1}) / double(c);
      auto go = torch::rand({3}) + 0.5;  // d loss / d d_v
      auto ar = a0.to(torch::kDouble).requires_grad_(true), br = b0.to(torch::kDouble).requires_grad_(grad_b);
      auto ref = loss::lpips_tap_distance(ar, br, w.to(torch::kDouble));
      (ref * go.to(torch::kDouble)).sum().backward();

      const auto cl = at::MemoryFormat::ChannelsLast;
      auto a = a0.cuda().contiguous(cl).requires_grad_(true), b = b0.cuda().contiguous(cl).requires_grad_(grad_b);
      REQUIRE(loss::lpips_tap_fused(a, b));
      auto d = loss::lpips_tap_distance(a, b, w.cuda());
      INFO("C = " << c << " grad_b " << grad_b << " fused " << d.cpu() << " reference " << ref);
      CHECK(d.scalar_type() == torch::kFloat);
      (d * go.cuda()).sum().backward();
      CHECK(test::rel_error(d, ref) < 1e-5);  // fp32 maths on the same bf16 inputs
      CHECK(test::rel_error(a.grad(), ar.grad()) < 1e-2);  // bf16 gradients
      if (grad_b) CHECK(test::rel_error(b.grad(), br.grad()) < 1e-2);
      else CHECK_FALSE(b.grad().defined());
    }
  }
  // NCHW or fp32 features take the ATen path.
  auto f = torch::rand({1, 64, 4, 4}, torch::kCUDA).to(torch::kBFloat16);
  CHECK_FALSE(loss::lpips_tap_fused(f, f));
  auto fcl = torch::rand({1, 64, 4, 4}, torch::kCUDA).contiguous(at::MemoryFormat::ChannelsLast);
  CHECK_FALSE(loss::lpips_tap_fused(fcl, fcl));
}

TEST_CASE("LPIPS in bf16 on CUDA (fused taps) is near the fp32 CPU value and gradient", "[loss][cuda]") {
  FLAT_REQUIRE_CUDA();
  torch::manual_seed(4);
  loss::Lpips cpu_net;
  loss::Lpips gpu_net;
  {
    torch::NoGradGuard guard;
    auto src = cpu_net->parameters();
    auto dst = gpu_net->parameters();
    for (size_t i = 0; i < src.size(); ++i) dst[i].copy_(src[i]);
  }
  gpu_net->to(at::kCUDA);
  auto m = make_images(3, 32, 48);
  auto a = m.rgb.to(at::kFloat).requires_grad_(true);
  auto ref = loss::lpips_distance(cpu_net, a, m.target.to(at::kFloat), {.max_size = 0, .chunk = 2});
  ref.sum().backward();
  for (bool checkpoint : {false, true}) {
    auto ag = m.rgb.to(at::kCUDA, at::kFloat).requires_grad_(true);
    auto d = loss::lpips_distance(gpu_net, ag, m.target.to(at::kCUDA, at::kFloat),
                                  {.max_size = 0, .chunk = 2, .checkpoint = checkpoint, .bf16 = true});
    d.sum().backward();
    INFO("checkpoint " << checkpoint << " bf16 cuda " << d.cpu() << " fp32 cpu " << ref);
    CHECK(test::rel_error(d, ref) < 3e-2);
    CHECK(test::rel_error(ag.grad(), a.grad()) < 1e-1);
  }
}
