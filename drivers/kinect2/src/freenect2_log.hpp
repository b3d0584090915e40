// libfreenect2's log, routed through one process-wide logger that prints to stderr (the journal,
// under systemd) and remembers the last error, so that "could not open the device" can say why.
#pragma once

#include <string>

namespace depthfuse::kinect2 {

// Installs the logger once per process. It prints warnings and errors; LIBFREENECT2_LOGGER_LEVEL
// (none, error, warning, info, debug) overrides that as it does for libfreenect2's own logger.
void install_freenect2_log();

// The last error libfreenect2 logged since clear_last_freenect2_error(), or "".
std::string last_freenect2_error();
void clear_last_freenect2_error();

}  // namespace depthfuse::kinect2
