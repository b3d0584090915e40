// What the operator's web server allows each client, and the book of open connections that holds
// to it: connections in all and per address, pages (WebSockets) in all and per address. When a new
// connection finds its address's share or the whole table full, the connection that has waited
// longest for a request it never finished makes room, unless bytes of its request are arriving
// right then: a client that opens connections and sends nothing (or sends slowly) cannot keep a
// quick one out, even from its own address. Connections answering a request and pages are never
// made to make room. No sockets here: the server (web_server.cpp) asks, and does what the answer
// says.
#pragma once

#include <atomic>
#include <chrono>
#include <cstddef>
#include <cstdint>
#include <functional>
#include <map>
#include <string>

namespace depthfuse::monitor {

struct WebLimits {
  size_t max_connections = 128;
  size_t max_connections_per_address = 32;  // on loopback every SSH-tunnelled user is one address
  size_t max_pages = 32;
  size_t max_pages_per_address = 8;
  // A request's headers and body must arrive within this of the connection's start (or of the
  // previous answer on a kept-alive connection); a client that takes nothing of an answer for
  // send_timeout is closed.
  std::chrono::milliseconds request_timeout{3000};
  std::chrono::milliseconds send_timeout{5000};
  // A page that has taken none of what it was sent for this long is dropped.
  std::chrono::milliseconds page_stall_timeout{5000};
  size_t max_page_queue_bytes = 8u << 20;  // beyond it, the page is dropped
  // The page only listens: a frame (message) from it larger than this closes its connection,
  // checked on the frame's header, before its payload is read.
  size_t max_client_message_bytes = 16;
  int page_send_buffer_bytes = 256 << 10;  // the kernel's share per page (SO_SNDBUF)
};

// What the server refused or dropped, for the monitor's heartbeat. Any thread reads them.
struct WebCounters {
  std::atomic<int64_t> connections_refused{0};  // the table was full of busy connections
  std::atomic<int64_t> connections_evicted{0};  // an idle or slow one made room
  std::atomic<int64_t> requests_timed_out{0};
  std::atomic<int64_t> requests_too_large{0};   // headers or body beyond their bounds
  std::atomic<int64_t> origin_refused{0};       // another site's page, or a Host not ours
  std::atomic<int64_t> pages_refused{0};        // too many pages
  std::atomic<int64_t> pages_dropped{0};        // a page that did not read
  std::atomic<int64_t> client_frames_refused{0};  // a page sent more than a few bytes
  std::atomic<int64_t> commands_taken{0};       // commands from the page passed on
};

class ConnectionTable {
 public:
  using Clock = std::chrono::steady_clock;
  explicit ConnectionTable(const WebLimits& limits) : limits_(limits) {}

  struct Admission {
    bool admitted = false;
    uint64_t evict = 0;  // when not 0: a connection, already out of the table, to close
  };
  // Whether a waiting connection may make room now (false: bytes of its request are arriving).
  using EvictableFn = std::function<bool(uint64_t id)>;
  // A new connection from `address`; it starts waiting for its request.
  Admission admit(uint64_t id, const std::string& address, Clock::time_point now,
                  const EvictableFn& evictable);
  // Waiting for a request since `since` (may be made to make room) / answering one (may not).
  void waiting(uint64_t id, Clock::time_point since);
  void busy(uint64_t id);
  // The connection becomes a page; false when there are too many (it stays as it was).
  bool make_page(uint64_t id);
  // Gone (an id no longer in the table is ignored).
  void remove(uint64_t id);

  size_t size() const { return entries_.size(); }
  size_t pages() const { return pages_; }

 private:
  enum class State { kWaiting, kBusy, kPage };
  struct Entry {
    std::string address;
    State state = State::kWaiting;
    Clock::time_point since;
  };
  struct PerAddress {
    size_t connections = 0, pages = 0;
  };
  // The evictable connection waiting longest, from `address` (or any when null); 0 when none.
  uint64_t longest_waiting(const std::string* address, const EvictableFn& evictable) const;

  WebLimits limits_;
  std::map<uint64_t, Entry> entries_;
  std::map<std::string, PerAddress> per_address_;
  size_t pages_ = 0;
};

}  // namespace depthfuse::monitor
