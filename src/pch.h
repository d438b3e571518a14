// Precompiled header shared by every module: libtorch is by far the most
// expensive include, so it is parsed once per build.
#pragma once
#include <torch/torch.h>
#include <algorithm>
#include <cmath>
#include <cstdint>
#include <map>
#include <memory>
#include <optional>
#include <stdexcept>
#include <string>
#include <vector>
