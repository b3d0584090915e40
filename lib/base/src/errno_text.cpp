#include "depthfuse/base/errno_text.hpp"

#include <string.h>

namespace depthfuse {

std::string errno_text(int error) {
  char buffer[256];
  // GNU strerror_r returns the text, which may or may not be in `buffer`; strerror() is not
  // thread-safe.
  return ::strerror_r(error, buffer, sizeof(buffer));
}

}  // namespace depthfuse
