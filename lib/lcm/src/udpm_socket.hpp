// The receiving side of an udpm URL: a UDP socket bound to the URL's port and joined to its
// multicast group, as liblcm's own receiver would be, so that liblcm clients (lcm-spy,
// lcm-logger, Python and Java programs) and depthfuse programs hear each other. Owned by
// LcmTransport; used from the thread that calls LcmTransport::handle.
#pragma once

#include <cstddef>
#include <cstdint>
#include <memory>
#include <vector>

#include "depthfuse/lcm/transport.hpp"
#include "depthfuse/status.hpp"

namespace depthfuse::lcm {

class UdpmSocket {
 public:
  struct Datagram {
    const uint8_t* data = nullptr;
    size_t size = 0;
    uint64_t sender = 0;  // the sender's IPv4 address and port, as one key
  };

  static Result<std::unique_ptr<UdpmSocket>> open(const LcmUrl& url);
  ~UdpmSocket();
  UdpmSocket(const UdpmSocket&) = delete;
  UdpmSocket& operator=(const UdpmSocket&) = delete;

  int fd() const { return fd_; }

  // Waits up to timeout_ms for a datagram. Nothing on timeout or when a signal interrupts the
  // wait. The datagram's bytes stay valid until the next call.
  Result<std::optional<Datagram>> receive(int timeout_ms);

 private:
  explicit UdpmSocket(int fd) : fd_(fd), buffer_(65536) {}

  int fd_;
  std::vector<uint8_t> buffer_;
};

}  // namespace depthfuse::lcm
