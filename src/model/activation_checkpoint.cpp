#include "flat/model/activation_checkpoint.h"

#include <ATen/autocast_mode.h>
#include <torch/csrc/autograd/custom_function.h>
#include <torch/csrc/autograd/autograd.h>
#include <ATen/core/ivalue.h>

#include "flat/core/autocast_scope.h"
#include "flat/core/error.h"

namespace flat::model {

namespace {

// The block travels through the autograd context as a capsule.
struct BlockHolder : torch::CustomClassHolder {
  std::function<at::Tensor(const at::Tensor&)> block;
  bool autocast_cuda = false;  // bf16 autocast on CUDA during the forward (AutocastScope's only mode)
};

struct CheckpointFunction : public torch::autograd::Function<CheckpointFunction> {
  static at::Tensor forward(torch::autograd::AutogradContext* ctx, const at::Tensor& x,
                            c10::intrusive_ptr<BlockHolder> holder) {
    ctx->save_for_backward({x});
    ctx->saved_data["block"] = c10::IValue::make_capsule(holder);
    // Inside forward() autograd is off: the block keeps no graph.
    return holder->block(x);
  }

  static torch::autograd::variable_list backward(torch::autograd::AutogradContext* ctx,
                                                 torch::autograd::variable_list grads) {
    auto x = ctx->get_saved_variables()[0];
    auto holder = c10::static_intrusive_pointer_cast<BlockHolder>(ctx->saved_data["block"].toCapsule());
    auto input = x.detach().requires_grad_(x.requires_grad());
    at::Tensor y;
    {
      torch::AutoGradMode enable(true);
      // The forward ran under the caller's autocast; the backward may not.
      AutocastScope autocast(holder->autocast_cuda, at::kCUDA);
      y = holder->block(input);
    }
    FLAT_CHECK(y.sizes() == grads[0].sizes(), "checkpointed: the recomputed block output differs in shape");
    torch::autograd::backward({y}, {grads[0]});
    return {input.requires_grad() ? input.grad() : at::Tensor(), at::Tensor()};
  }
};

}  // namespace

at::Tensor checkpointed(const std::function<at::Tensor(const at::Tensor&)>& block, const at::Tensor& x) {
  // An input without gradient would give the Function no graph node, and the
  // block's parameters no gradient: such a block runs as usual.
  if (!at::GradMode::is_enabled() || !x.requires_grad()) return block(x);
  auto holder = c10::make_intrusive<BlockHolder>();
  holder->block = block;
  holder->autocast_cuda = at::autocast::is_autocast_enabled(at::kCUDA);
  return CheckpointFunction::apply(x, holder);
}

}  // namespace flat::model
