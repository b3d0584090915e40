// What the operator's web server answers, apart from the sockets that carry it (web_server.hpp):
// the page's files from web_root, GET /api/status, GET /api/auth and POST /api/command, and whether
// a request may open the page's WebSocket /ws. Every request first passes the origin policy
// (origin_policy.hpp): another site's page, or a name that is not this monitor's, is refused
// before anything else, and no answer ever approves a cross-origin request (no CORS headers at
// all). Runs on the server's thread; takes no lock of its own.
#pragma once

#include <functional>
#include <optional>
#include <string>
#include <string_view>

#include "depthfuse/status.hpp"
#include "origin_policy.hpp"
#include "page_auth.hpp"
#include "web_limits.hpp"

namespace depthfuse::monitor {

// "action=start&argument=NAME" is far smaller; a larger request body is refused as it is declared.
constexpr size_t kMaxRequestBodyBytes = 4096;
constexpr size_t kMaxRequestHeaderBytes = 8192;

struct PageRequest {
  std::string_view method, target;
  std::string_view host;                  // "" when absent
  std::optional<std::string_view> origin;
  bool page_header = false;               // X-Depthfuse is present
  std::optional<std::string> signature;   // X-Depthfuse-Signature
  std::string_view body;
  std::string_view peer;                  // the client's address, for the log
};

struct PageReply {
  unsigned status = 200;
  std::string content_type = "application/json";
  std::string body;
  std::string file;    // when not empty: this file is the body (a page's file)
};

class PageRoutes {
 public:
  // Takes a command for the fusion daemon (action name, argument) and returns its id, or an
  // error (unknown action, too many waiting).
  using CommandFn = std::function<Result<int64_t>(const std::string& action, const std::string& argument)>;
  using StatusFn = std::function<std::string()>;

  // `auth` null without a rig key. `counters` outlive the routes.
  PageRoutes(std::string web_root, OriginPolicy policy, PageCommandAuth* auth, CommandFn command,
             StatusFn status_json, WebCounters* counters);

  PageReply answer(const PageRequest& r) const;
  // A WebSocket upgrade: none when `r` may open the page's WebSocket, else the refusal.
  std::optional<PageReply> refuse_page(const PageRequest& r) const;

 private:
  std::optional<PageReply> refuse_foreign(const PageRequest& r) const;
  PageReply auth_settings() const;
  PageReply command(const PageRequest& r) const;
  PageReply file(std::string_view path) const;

  std::string web_root_;
  OriginPolicy policy_;
  PageCommandAuth* auth_;
  CommandFn command_;
  StatusFn status_json_;
  WebCounters* counters_;
  mutable bool host_refusal_logged_ = false, origin_refusal_logged_ = false;
};

// The JSON error body the API answers with: {"error": "..."}.
PageReply json_error(unsigned status, const std::string& message);

}  // namespace depthfuse::monitor
