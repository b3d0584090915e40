// Which requests come from the operator's page. A browser says which page made a request in its
// Origin header, and which name it addressed in Host; the page's own requests carry its own
// origin, or (GETs) none. Another site's page can make the browser send requests here (a form
// POST, a WebSocket, fetch after a preflight) but cannot change Origin, and a name of its own
// that it points at 127.0.0.1 (DNS rebinding) shows in Host. So:
//  - Origin, when present, must be the page's: http:// or https:// followed by the request's
//    Host (behind a TLS proxy that keeps Host), or one of the configured origins (a proxy that
//    rewrites Host);
//  - served on loopback, Host must be a loopback address or localhost (any port: SSH tunnels
//    map ports), or the host of a configured origin.
// A client that is not a browser sends what it likes; the rig key (page_auth.hpp) is what
// protects commands from those.
#pragma once

#include <string>
#include <string_view>
#include <vector>

#include "depthfuse/status.hpp"

namespace depthfuse::monitor {

class OriginPolicy {
 public:
  // `allowed_origins` as parse_origins() returns them.
  OriginPolicy(bool loopback_only, std::vector<std::string> allowed_origins)
      : loopback_only_(loopback_only), allowed_(std::move(allowed_origins)) {}

  // `host`: the Host header ("" when the request had none, as HTTP/1.0 clients send).
  bool host_allowed(std::string_view host) const;
  bool origin_allowed(std::string_view origin, std::string_view host) const;

 private:
  bool loopback_only_;
  std::vector<std::string> allowed_;
};

// "https://rig.example, https://10.0.0.5:8443" as origins, lower case and without a trailing
// slash; an error names an entry that is not scheme://host[:port] with scheme http or https.
Result<std::vector<std::string>> parse_origins(std::string_view list);

// localhost, 127.x.y.z or [::1], without the port.
bool is_loopback_host(std::string_view host_without_port);

}  // namespace depthfuse::monitor
