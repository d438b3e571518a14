#include "flat/model/wan_vae_config.h"

#include <string>

#include "flat/core/error.h"

namespace flat::model {

void WanVAEConfig::check() const {
  FLAT_CHECK(dim > 0 && z_dim > 0 && num_res_blocks > 0, "WanVAEConfig: dim, z_dim, num_res_blocks must be positive");
  FLAT_CHECK(dim_mult.size() >= 2, "WanVAEConfig: dim_mult needs at least 2 stages");
  FLAT_CHECK(temporal_downsample.size() + 1 == dim_mult.size(),
             "WanVAEConfig: temporal_downsample needs one entry per downsampling stage (" +
                 std::to_string(dim_mult.size() - 1) + "), got " + std::to_string(temporal_downsample.size()));
}

}  // namespace flat::model
