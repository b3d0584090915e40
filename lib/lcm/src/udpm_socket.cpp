#include "udpm_socket.hpp"

#include <arpa/inet.h>
#include <netinet/in.h>
#include <poll.h>
#include <sys/socket.h>
#include <unistd.h>

#include <time.h>

#include <cerrno>
#include <optional>

#include "depthfuse/base/clock.hpp"
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

namespace {
// The largest UDP payload over IPv4 is 65507 bytes: one slot holds any datagram whole.
constexpr size_t kSlotBytes = 65536;
// Datagrams closer together than this count as a stream.
constexpr int64_t kStreamGapNs = 1'000'000;
// How long a stream's next datagrams are left to gather in the kernel: the kernel wakes a
// receiver for each datagram, and here a wakeup costs several times what checking a datagram
// does. Half a millisecond is little next to a frame's 33 ms, and what arrives meanwhile (five
// datagrams at the flood benchmark's 10^4 a second, a frame's fragments) is far from filling the
// 4 MiB receive buffer.
constexpr int64_t kGatherNs = 500'000;
}  // namespace

UdpmSocket::UdpmSocket(int fd)
    : fd_(fd),
      buffers_(new uint8_t[kBatch * kSlotBytes]),
      headers_(kBatch),
      iovecs_(kBatch),
      from_(kBatch) {}

UdpmSocket::~UdpmSocket() { ::close(fd_); }

Result<bool> UdpmSocket::fill() {
  for (size_t i = 0; i < kBatch; ++i) {
    iovecs_[i] = iovec{buffers_.get() + i * kSlotBytes, kSlotBytes};
    headers_[i] = mmsghdr{};
    headers_[i].msg_hdr.msg_name = &from_[i];
    headers_[i].msg_hdr.msg_namelen = sizeof(sockaddr_in);
    headers_[i].msg_hdr.msg_iov = &iovecs_[i];
    headers_[i].msg_hdr.msg_iovlen = 1;
  }
  const int n = ::recvmmsg(fd_, headers_.data(), static_cast<unsigned>(kBatch), MSG_DONTWAIT,
                           nullptr);
  if (n < 0 && (errno == EINTR || errno == EAGAIN || errno == EWOULDBLOCK)) {
    backlog_ = false;
    return false;
  }
  if (n < 0) return io_error("receiving LCM datagrams failed: " + errno_text());
  count_ = static_cast<size_t>(n);
  next_ = 0;
  backlog_ = count_ == kBatch;
  const int64_t now = steady_ns();
  streaming_ = now - last_fill_ns_ < kStreamGapNs;
  last_fill_ns_ = now;
  return count_ > 0;
}

Result<std::optional<UdpmSocket::Datagram>> UdpmSocket::receive(int timeout_ms) {
  if (next_ >= count_) {
    count_ = next_ = 0;
    // A full last batch: more are probably queued, try without waiting first. Otherwise the queue
    // was empty a moment ago, and poll is the one call that waits.
    bool got = false;
    if (!backlog_ && streaming_ && timeout_ms > 0) {
      const timespec gather{0, kGatherNs};
      ::nanosleep(&gather, nullptr);  // an interruption only shortens it
      backlog_ = true;                // look without waiting first
    }
    if (backlog_) {
      auto r = fill();
      if (!r) return r.status();
      got = *r;
    }
    if (!got) {
      pollfd p{fd_, POLLIN, 0};
      const int ready = ::poll(&p, 1, timeout_ms);
      if (ready < 0 && errno == EINTR) return std::optional<Datagram>();
      if (ready < 0) return io_error("waiting for LCM datagrams failed: " + errno_text());
      if (ready == 0) return std::optional<Datagram>();
      auto r = fill();
      if (!r) return r.status();
      if (!*r) return std::optional<Datagram>();
    }
  }
  const size_t i = next_++;
  const sockaddr_in& from = from_[i];
  const uint64_t sender = (uint64_t{ntohl(from.sin_addr.s_addr)} << 16) | ntohs(from.sin_port);
  return std::optional<Datagram>(
      Datagram{buffers_.get() + i * kSlotBytes, headers_[i].msg_len, sender});
}

}  // namespace depthfuse::lcm
