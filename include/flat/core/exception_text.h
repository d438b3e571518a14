// The message of an exception for a message of ours: libtorch's c10::Error
// without the C++ stack trace its what() appends (23 lines of frames that
// bury the message), anything else as what() says.
#pragma once
#include <exception>
#include <string>

namespace flat {

std::string exception_text(const std::exception& e);

}  // namespace flat
