#include "flat/core/error.h"

#include <exception>
#include <filesystem>

#include <c10/util/Exception.h>
#include <spdlog/spdlog.h>

namespace flat {

int report_current_error() {
  try {
    throw;
  } catch (const Error& e) {
    spdlog::error("{}", e.what());
  } catch (const std::filesystem::filesystem_error& e) {
    // A filesystem call that had no message of ours (an output folder that is
    // read-only or a file): lead with the path and say what failed.
    std::string what = e.what();  // "filesystem error: cannot create directories: Permission denied [p]"
    const std::string prefix = "filesystem error: ";
    if (what.rfind(prefix, 0) == 0) what = what.substr(prefix.size());
    if (const auto bracket = what.find(" ["); bracket != std::string::npos) what = what.substr(0, bracket);
    std::string paths = "'" + e.path1().string() + "'";
    if (!e.path2().empty()) paths += " (to '" + e.path2().string() + "')";
    spdlog::error("{}: {}", paths, what);
  } catch (const c10::Error& e) {
    // libtorch's own errors (an allocation that cannot fit, a kernel's
    // check): the message, without the C++ stack trace that follows it.
    spdlog::error("unexpected error: {}", e.what_without_backtrace());
  } catch (const std::exception& e) {
    spdlog::error("unexpected error: {}", e.what());
  } catch (...) {
    spdlog::error("unexpected error (not a std::exception)");
  }
  return 1;
}

}  // namespace flat
