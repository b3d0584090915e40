// The host's part of an udpm URL (see host_diagnosis.hpp).
#include "depthfuse/lcm/host_diagnosis.hpp"

#include <arpa/inet.h>
#include <netinet/in.h>
#include <sys/socket.h>
#include <unistd.h>

#include <cerrno>
#include <cstring>
#include <fstream>

namespace depthfuse::lcm {

std::string route_fix(const std::string& group) {
  return "LCM's udpm transport needs a route for the multicast group. Check it with "
         "'ip route get " + group + "' and 'ip route show table all'; on a host where no "
         "interface carries multicast (a bare container, a board without a network cable) add "
         "one on loopback: 'sudo ip route add 224.0.0.0/4 dev lo' (tools/lcm/route does this; "
         "docs/live.md explains how to make it permanent)";
}

int64_t read_rmem_max() {
  std::ifstream in("/proc/sys/net/core/rmem_max");
  int64_t value = -1;
  if (!(in >> value)) return -1;
  return value;
}

LcmDiagnosis diagnose_lcm_url(const LcmUrl& url) {
  LcmDiagnosis d;
  if (url.provider != "udpm") return d;

  // connect() on a UDP socket asks the kernel for a route without sending anything: ENETUNREACH
  // is exactly the condition under which LCM's self-test fails.
  const int fd = ::socket(AF_INET, SOCK_DGRAM | SOCK_CLOEXEC, 0);
  if (fd >= 0) {
    sockaddr_in dest{};
    dest.sin_family = AF_INET;
    dest.sin_port = htons(static_cast<uint16_t>(url.port));
    inet_pton(AF_INET, url.multicast_group.c_str(), &dest.sin_addr);
    if (::connect(fd, reinterpret_cast<const sockaddr*>(&dest), sizeof(dest)) != 0) {
      const int err = errno;
      d.route = unavailable("no route to the LCM multicast group " + url.multicast_group + " (" +
                            std::strerror(err) + "). " + route_fix(url.multicast_group));
    }
    ::close(fd);
  }

  const int64_t rmem_max = read_rmem_max();
  if (url.recv_buf_size < 0) {
    d.warnings.push_back(
        "LCM URL '" + url.text + "' sets no recv_buf_size: with the kernel's default receive "
        "buffer most 512x424 depth frames (7-14 UDP fragments each) are lost. Add "
        "'recv_buf_size=4194304' to the URL, e.g. " + default_lcm_url());
  } else if (rmem_max >= 0 && rmem_max < url.recv_buf_size) {
    d.warnings.push_back(
        "net.core.rmem_max is " + std::to_string(rmem_max) + " bytes, smaller than the " +
        std::to_string(url.recv_buf_size) + " the LCM URL asks for: the kernel caps the receive "
        "buffer and large frames will be lost. Raise it with 'sudo sysctl -w "
        "net.core.rmem_max=" + std::to_string(url.recv_buf_size) + "' and make it permanent with "
        "the sysctl drop-in (tools/lcm/sysctl-check --install, see docs/live.md)");
  }
  return d;
}

}  // namespace depthfuse::lcm
