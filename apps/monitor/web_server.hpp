// The operator's page over HTTP and WebSocket (Boost.Beast on Boost.Asio, Debian's libboost-dev):
// the page's files, GET /api/status, GET /api/auth, POST /api/command (page_routes.hpp) and the
// WebSocket /ws, which pushes the status and the map preview (MapStore) to every page.
//
// One thread of the server's runs every connection, without ever waiting on one: reads and
// writes are asynchronous, so a client that is slow, silent or never reads holds a slot of the
// connection table (web_limits.hpp) and nothing else, and /api/status is answered at once
// whatever the other clients do. What a client may send is bounded before it is buffered:
// headers and body by size and time, a page's own frames by their declared length. Each page has
// a bounded send queue and gets more of the map only when it has taken what it was sent; a page
// that takes nothing for a while is dropped. Neither the requests nor the pushes ever wait on the
// monitor's LCM loop.
#pragma once

#include <cstdint>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include "depthfuse/lcm/message_auth.hpp"
#include "depthfuse/status.hpp"
#include "map_store.hpp"
#include "page_auth.hpp"
#include "page_routes.hpp"
#include "web_limits.hpp"

namespace depthfuse::monitor {

struct WebServerOptions {
  std::string listen;          // "ADDR:PORT"; PORT 0 takes a free one
  bool allow_remote = false;   // else ADDR must be loopback; another ADDR needs `key` too
  std::string web_root;        // index.html and the scripts
  // With a rig key, a command is carried out only when the page signed it with the key, signed
  // within max_skew_us of this host's clock; without one, every command from the page is.
  std::optional<lcm::RigKey> key;
  int64_t max_skew_us = 2000000;
  // Origins besides the page's own whose requests are taken (origin_policy.hpp): a TLS proxy
  // that changes the Host, e.g. "https://rig.example".
  std::vector<std::string> allowed_origins;
  WebLimits limits;
};

class WebServer {
 public:
  using CommandFn = PageRoutes::CommandFn;

  static Result<std::unique_ptr<WebServer>> start(const WebServerOptions& options,
                                                  const MapStore* store, CommandFn command);
  ~WebServer();
  WebServer(const WebServer&) = delete;
  WebServer& operator=(const WebServer&) = delete;

  // "http://127.0.0.1:8080/"
  const std::string& url() const { return url_; }
  // The LCM thread: the newest status, as JSON.
  void set_status(std::string json);

  // Null without a rig key. Any thread.
  const PageCommandAuth* command_auth() const { return auth_.get(); }
  // Any thread.
  const WebCounters& counters() const { return counters_; }

  class Core;  // the sockets and their thread (web_server.cpp)

 private:
  WebServer() = default;

  std::unique_ptr<PageCommandAuth> auth_;
  WebCounters counters_;
  std::string url_;
  std::unique_ptr<Core> core_;
};

}  // namespace depthfuse::monitor
