#include "udpm_socket.hpp"

#include <arpa/inet.h>
#include <netinet/in.h>
#include <poll.h>
#include <sys/socket.h>
#include <unistd.h>

#include <cerrno>
#include <optional>

#include "depthfuse/base/errno_text.hpp"

namespace depthfuse::lcm {

Result<std::unique_ptr<UdpmSocket>> UdpmSocket::open(const LcmUrl& url) {
  const int fd = ::socket(AF_INET, SOCK_DGRAM | SOCK_CLOEXEC, 0);
  if (fd < 0) return io_error("cannot create a UDP socket: " + errno_text());
  std::unique_ptr<UdpmSocket> socket(new UdpmSocket(fd));
  const auto fail = [&](const std::string& what) {
    return io_error("LCM URL '" + url.text + "': cannot " + what + ": " + errno_text());
  };

  // Every LCM process on the host listens on the same port.
  const int one = 1;
  if (::setsockopt(fd, SOL_SOCKET, SO_REUSEADDR, &one, sizeof(one)) != 0)
    return fail("set SO_REUSEADDR");
  if (url.recv_buf_size > 0) {
    const int size = static_cast<int>(std::min<int64_t>(url.recv_buf_size, INT32_MAX));
    // The kernel caps it at net.core.rmem_max; diagnose_lcm_url() warns about that.
    if (::setsockopt(fd, SOL_SOCKET, SO_RCVBUF, &size, sizeof(size)) != 0)
      return fail("set the receive buffer");
  }
  sockaddr_in local{};
  local.sin_family = AF_INET;
  local.sin_addr.s_addr = htonl(INADDR_ANY);
  local.sin_port = htons(static_cast<uint16_t>(url.port));
  if (::bind(fd, reinterpret_cast<const sockaddr*>(&local), sizeof(local)) != 0)
    return fail("bind UDP port " + std::to_string(url.port));
  ip_mreq membership{};
  if (::inet_pton(AF_INET, url.multicast_group.c_str(), &membership.imr_multiaddr) != 1)
    return invalid_argument("LCM URL '" + url.text + "': bad multicast group");
  membership.imr_interface.s_addr = htonl(INADDR_ANY);
  if (::setsockopt(fd, IPPROTO_IP, IP_ADD_MEMBERSHIP, &membership, sizeof(membership)) != 0)
    return fail("join the multicast group " + url.multicast_group);
  return socket;
}

UdpmSocket::~UdpmSocket() { ::close(fd_); }

Result<std::optional<UdpmSocket::Datagram>> UdpmSocket::receive(int timeout_ms) {
  pollfd p{fd_, POLLIN, 0};
  const int ready = ::poll(&p, 1, timeout_ms);
  if (ready < 0 && errno == EINTR) return std::optional<Datagram>();
  if (ready < 0) return io_error("waiting for LCM datagrams failed: " + errno_text());
  if (ready == 0) return std::optional<Datagram>();

  sockaddr_in from{};
  socklen_t from_size = sizeof(from);
  const ssize_t n = ::recvfrom(fd_, buffer_.data(), buffer_.size(), MSG_DONTWAIT,
                               reinterpret_cast<sockaddr*>(&from), &from_size);
  if (n < 0 && (errno == EINTR || errno == EAGAIN || errno == EWOULDBLOCK))
    return std::optional<Datagram>();
  if (n < 0) return io_error("receiving an LCM datagram failed: " + errno_text());
  const uint64_t sender = (uint64_t{ntohl(from.sin_addr.s_addr)} << 16) | ntohs(from.sin_port);
  return std::optional<Datagram>(Datagram{buffer_.data(), static_cast<size_t>(n), sender});
}

}  // namespace depthfuse::lcm
