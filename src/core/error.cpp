#include "flat/core/error.h"

#include <exception>

#include <spdlog/spdlog.h>

namespace flat {

int report_current_error() {
  try {
    throw;
  } catch (const Error& e) {
    spdlog::error("{}", e.what());
  } catch (const std::exception& e) {
    spdlog::error("unexpected error: {}", e.what());
  } catch (...) {
    spdlog::error("unexpected error (not a std::exception)");
  }
  return 1;
}

}  // namespace flat
