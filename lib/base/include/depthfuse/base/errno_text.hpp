// The text of an errno value, for error messages that name what the OS refused.
#pragma once

#include <cerrno>
#include <string>

namespace depthfuse {

// strerror's text for `error` (default: the current errno), safe from any thread.
std::string errno_text(int error = errno);

}  // namespace depthfuse
