// The receiving side of an udpm URL: a UDP socket bound to the URL's port and joined to its
// multicast group, as liblcm's own receiver would be, so that liblcm clients (lcm-spy,
// lcm-logger, Python and Java programs) and depthfuse programs hear each other. Owned by
// LcmTransport; used from the thread that calls LcmTransport::handle.
#pragma once

#include <netinet/in.h>
#include <sys/socket.h>
#include <sys/uio.h>

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

  // Datagrams taken from the kernel in one call at most. On this machine a system call costs
  // more than checking and dropping a hostile datagram, so under a flood they are taken in
  // batches (recvmmsg) rather than with a poll and a recvfrom each.
  static constexpr size_t kBatch = 16;

 private:
  explicit UdpmSocket(int fd);
  // Takes up to kBatch queued datagrams without waiting; false when none was queued.
  Result<bool> fill();

  int fd_;
  std::unique_ptr<uint8_t[]> buffers_;  // kBatch slots of kSlotBytes, touched only when used
  std::vector<mmsghdr> headers_;
  std::vector<iovec> iovecs_;
  std::vector<sockaddr_in> from_;
  size_t count_ = 0;  // datagrams in the batch
  size_t next_ = 0;   // the next one receive() hands out
  // Whether the last batch was full: then more are probably queued and the poll is skipped.
  bool backlog_ = false;
  // When the last batch arrived, and whether it came soon after the one before: datagrams are
  // streaming in, and the next batch is left to gather for a moment (kGatherUs) rather than
  // taken one datagram per wakeup.
  int64_t last_fill_ns_ = 0;
  bool streaming_ = false;
};

}  // namespace depthfuse::lcm
