// Hopper implicit-GEMM 3D convolution (CUTLASS 3 collective builders): GEMM
// M = output pixels (n,z,p,q), N = output channels k, K = filter taps x input
// channels (t,r,s,c). A tiles come straight from the channels-last activation
// through TMA im2col loads (the padding is TMA's out-of-bounds zero fill, so
// no im2col buffer and no padded copy); the epilogue adds the bias and, when
// given, the residual (the skip connection of a residual block), so the sum
// needs no extra pass over memory. Compiled for sm_90a only (warpgroup MMA).
#include "conv3d_sm90_kernel.h"

#include <cute/tensor.hpp>
#include <cutlass/kernel_hardware_info.hpp>
#include <cutlass/conv/collective/collective_builder.hpp>
#include <cutlass/conv/convnd_problem_shape.hpp>
#include <cutlass/conv/device/conv_universal_adapter.hpp>
#include <cutlass/conv/dispatch_policy.hpp>
#include <cutlass/conv/kernel/conv_universal.hpp>
#include <cutlass/cutlass.h>
#include <cutlass/epilogue/collective/collective_builder.hpp>
#include <cutlass/epilogue/fusion/operations.hpp>

namespace flat::model::cuda {
namespace {

using namespace cute;
using Element = cutlass::bfloat16_t;
using Layout = cutlass::layout::TensorNDHWC;  // activations NDHWC, filters KTRSC, output NZPQK
constexpr int kAlign = 8;                     // 16-byte TMA alignment in bf16 elements
constexpr auto kFprop = cutlass::conv::Operator::kFprop;

// One tile configuration: (output pixels, output channels, input channels) per
// CTA step. A single consumer warpgroup per CTA (the only warp-specialised
// schedule CUTLASS offers for conv on sm_90).
template <int TileM, int TileN, int TileK>
struct Kernel {
  using TileShape = Shape<Int<TileM>, Int<TileN>, Shape<Int<TileK>>>;
  using ClusterShape = Shape<_1, _1, _1>;
  using Fusion = cutlass::epilogue::fusion::LinCombPerColBias<Element, float, Element, Element, float>;
  using Epilogue = typename cutlass::epilogue::collective::CollectiveBuilder<
      cutlass::arch::Sm90, cutlass::arch::OpClassTensorOp, TileShape, ClusterShape,
      cutlass::epilogue::collective::EpilogueTileAuto, float, float, Element, Layout, kAlign, Element, Layout,
      kAlign, cutlass::epilogue::TmaWarpSpecialized, Fusion>::CollectiveOp;
  using Mainloop = typename cutlass::conv::collective::CollectiveBuilder<
      cutlass::arch::Sm90, cutlass::arch::OpClassTensorOp, kFprop, Element, Layout, kAlign, Element, Layout, kAlign,
      float, TileShape, ClusterShape,
      cutlass::conv::collective::StageCountAutoCarveout<static_cast<int>(sizeof(typename Epilogue::SharedStorage))>,
      cutlass::conv::KernelImplicitTmaWarpSpecializedSm90>::CollectiveOp;
  using Problem = cutlass::conv::ConvProblemShape<kFprop, Mainloop::DispatchPolicy::NumSpatialDimensions>;
  using Conv = cutlass::conv::device::ConvUniversalAdapter<
      cutlass::conv::kernel::ConvUniversal<Problem, Mainloop, Epilogue>>;

  static Problem problem(const Conv3dProblem& p) {
    return Problem(cutlass::conv::Mode::kCrossCorrelation, {p.n, p.d, p.h, p.w, p.c}, {p.k, p.t, p.r, p.s, p.c},
                   {p.pad_d, p.pad_h, p.pad_w}, {p.pad_d, p.pad_h, p.pad_w}, {1, 1, 1}, {1, 1, 1}, 1);
  }

  static typename Conv::Arguments arguments(const Conv3dProblem& p, const void* x, const void* w, const void* bias,
                                            const void* residual, void* out) {
    const Problem shape = problem(p);
    // Output strides (q,p,z,n) from the problem's packed NZPQK strides.
    typename Conv::ConvKernel::StrideC stride_c;
    typename Conv::ConvKernel::StrideD stride_d;
    cute::for_each(cute::make_seq<cute::rank<0>(decltype(stride_c){})>{}, [&](auto i) {
      cute::get<0, i>(stride_c) = shape.stride_C[Problem::RankT - 2 - i];
      cute::get<0, i>(stride_d) = shape.stride_C[Problem::RankT - 2 - i];
    });
    typename Conv::Arguments args{
        shape,
        {static_cast<const Element*>(x), static_cast<const Element*>(w)},
        {{}, static_cast<const Element*>(residual), stride_c, static_cast<Element*>(out), stride_d}};
    args.epilogue.thread.alpha = 1.f;
    args.epilogue.thread.beta = residual != nullptr ? 1.f : 0.f;
    args.epilogue.thread.bias_ptr = static_cast<const Element*>(bias);
    return args;
  }

  // The K loop tiles each filter tap's channels: TileK must divide them; the
  // outputs are stored 16 bytes at a time.
  static bool shape_ok(const Conv3dProblem& p) { return p.c % TileK == 0 && p.k % kAlign == 0; }

  static bool can_run(const Conv3dProblem& p) {
    return shape_ok(p) &&
           Conv::can_implement(arguments(p, nullptr, nullptr, nullptr, nullptr, nullptr)) == cutlass::Status::kSuccess;
  }

  static size_t workspace(const Conv3dProblem& p) {
    return Conv::get_workspace_size(arguments(p, nullptr, nullptr, nullptr, nullptr, nullptr));
  }

  static bool run(const Conv3dProblem& p, const void* x, const void* w, const void* bias, const void* residual,
                  void* out, void* ws, cudaStream_t stream) {
    if (!shape_ok(p)) return false;
    const auto args = arguments(p, x, w, bias, residual, out);
    Conv conv;
    if (conv.can_implement(args) != cutlass::Status::kSuccess) return false;
    if (conv.initialize(args, ws, stream) != cutlass::Status::kSuccess) return false;
    return conv.run(stream) == cutlass::Status::kSuccess && cudaPeekAtLastError() == cudaSuccess;
  }
};

// The configurations, by output width: 96 (the full-resolution 96-channel
// convs, whose 96 input channels need TileK 32), 128 and 192 (two or one
// N tiles for 384 and 192 outputs). 256-pixel tiles halve the filter loads
// per output of the narrow 96-output convs.
using K128x96x32 = Kernel<128, 96, 32>;
using K256x96x32 = Kernel<256, 96, 32>;
using K128x96x64 = Kernel<128, 96, 64>;
using K256x96x64 = Kernel<256, 96, 64>;
using K128x128x64 = Kernel<128, 128, 64>;
using K128x192x64 = Kernel<128, 192, 64>;

struct Entry {
  const char* name;
  bool (*can_run)(const Conv3dProblem&);
  size_t (*workspace)(const Conv3dProblem&);
  bool (*run)(const Conv3dProblem&, const void*, const void*, const void*, const void*, void*, void*,
              cudaStream_t);
};

template <class K>
constexpr Entry entry(const char* name) {
  return Entry{name, &K::can_run, &K::workspace, &K::run};
}

const Entry kEntries[] = {
    entry<K128x96x32>("128x96x32"),
    entry<K256x96x32>("256x96x32"),
    entry<K128x96x64>("128x96x64"),
    entry<K256x96x64>("256x96x64"),
    entry<K128x128x64>("128x128x64"),
    entry<K128x192x64>("128x192x64"),
};
constexpr int kCount = int(sizeof(kEntries) / sizeof(kEntries[0]));

}  // namespace

int conv3d_sm90_config_count() { return kCount; }

const char* conv3d_sm90_config_name(int config) {
  return config >= 0 && config < kCount ? kEntries[config].name : "?";
}

bool conv3d_sm90_can_run(int config, const Conv3dProblem& p) {
  return config >= 0 && config < kCount && kEntries[config].can_run(p);
}

size_t conv3d_sm90_workspace_bytes(int config, const Conv3dProblem& p) { return kEntries[config].workspace(p); }

bool conv3d_sm90_run(int config, const Conv3dProblem& p, const void* x, const void* w, const void* bias,
                     const void* residual, void* out, void* workspace, cudaStream_t stream) {
  // run() checks what can_run() does, once (this is every conv call's path).
  if (config < 0 || config >= kCount) return false;
  return kEntries[config].run(p, x, w, bias, residual, out, workspace, stream);
}

}  // namespace flat::model::cuda
