// What an udpm URL needs from the host, checked before LCM is asked, so that a program says why
// LCM cannot work here and how to fix it instead of LCM's bare self-test failure.
#pragma once

#include <cstdint>
#include <string>
#include <vector>

#include "depthfuse/lcm/url.hpp"
#include "depthfuse/status.hpp"

namespace depthfuse::lcm {

// net.core.rmem_max in bytes (/proc/sys/net/core/rmem_max), -1 when it cannot be read.
int64_t read_rmem_max();

//  - a route to the multicast group (`ip route get <group>`): without one LCM's self-test fails;
//  - net.core.rmem_max at least the recv_buf_size of the URL, else the kernel caps the buffer and
//    large frames (7-14 UDP fragments each) are lost.
struct LcmDiagnosis {
  Status route;                        // ok, or why there is none and how to add one
  std::vector<std::string> warnings;   // receive buffer problems
};
LcmDiagnosis diagnose_lcm_url(const LcmUrl& url);

// How to give the host a route to `group` (the commands to check and to add one).
std::string route_fix(const std::string& group);

}  // namespace depthfuse::lcm
