// An LCM URL, "<provider>://<address>[?options]": the parts of an udpm URL that the transport and
// the host diagnosis use, and the appliance's default. Only udpm is inspected; other providers
// (memq, file, tcpq) are passed to LCM unchanged.
#pragma once

#include <cstdint>
#include <string>

#include "depthfuse/status.hpp"

namespace depthfuse::lcm {

// The appliance's multicast group and port (LCM's own defaults): the one place they are written.
constexpr const char* kMulticastGroup = "239.255.76.67";
constexpr int kDefaultPort = 7667;

struct LcmUrl {
  std::string text;              // as given
  std::string provider;          // "udpm", "memq", ...
  std::string multicast_group;   // udpm: kMulticastGroup when the URL names none
  int port = 0;                  // udpm: kDefaultPort when the URL names none
  int ttl = 0;                   // udpm: 0 keeps traffic on this host
  int64_t recv_buf_size = -1;    // udpm: bytes asked for in the URL, -1 when absent
};

Result<LcmUrl> parse_lcm_url(const std::string& url);

// An udpm URL on the appliance's group at `port`, on this host only (ttl=0), with the receive
// buffer 512x424 frames need.
std::string udpm_url(int port);

// The URL of the appliance (same as LcmConfig::url): udpm_url(kDefaultPort).
std::string default_lcm_url();

// The URL with its udpm ttl set to 0 (traffic stays on this host); other URLs unchanged.
std::string url_with_ttl0(const LcmUrl& url);

}  // namespace depthfuse::lcm
