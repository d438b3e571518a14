// Width and depth of the Wan 2.1 VAE. The defaults are the pretrained model
// (../shared/docs/wan_vae.md); small `dim` values give the same architecture for CPU tests.
#pragma once
#include <cstdint>
#include <vector>

#include "flat/core/config.h"

namespace flat::model {

struct WanVAEConfig {
  int64_t dim = 96;                             // base width (the paper's 96)
  int64_t z_dim = 16;                           // latent channels
  std::vector<int64_t> dim_mult = {1, 2, 4, 4};  // width per stage
  int64_t num_res_blocks = 2;                    // encoder; the decoder has one more per stage
  std::vector<int64_t> temporal_downsample = {0, 1, 1};  // per encoder stage; decoder mirrors it

  template <class V>
  void visit(V& v) {
    v.field("dim", dim, config::positive(), "base channel width (96 = pretrained Wan 2.1)");
    v.field("z_dim", z_dim, config::positive(), "latent channels");
    v.field("dim_mult", dim_mult, config::positive(), "channel multiplier per stage");
    v.field("num_res_blocks", num_res_blocks, config::positive(), "residual blocks per encoder stage");
    v.field("temporal_downsample", temporal_downsample, config::range(0, 1),
            "1 where an encoder stage also halves time");
  }
  // Throws flat::Error on inconsistent values (e.g. wrong list lengths).
  void check() const;
};

}  // namespace flat::model
