// What the operator's web server answers (see page_routes.hpp).
#include "page_routes.hpp"

#include <algorithm>
#include <cctype>
#include <filesystem>
#include <utility>

#include "depthfuse/base/clock.hpp"
#include "depthfuse/base/log.hpp"
#include "depthfuse/daemon/status_json.hpp"

DF_LOG_CATEGORY(Web)

namespace depthfuse::monitor {

namespace {

constexpr size_t kMaxActionBytes = 31;
constexpr size_t kMaxArgumentBytes = 127;

int hex_digit(char c) {
  if (c >= '0' && c <= '9') return c - '0';
  if (c >= 'a' && c <= 'f') return c - 'a' + 10;
  if (c >= 'A' && c <= 'F') return c - 'A' + 10;
  return -1;
}

// A field of an application/x-www-form-urlencoded body, decoded: none when absent; false in *ok
// when it is not percent-encoded properly.
std::optional<std::string> form_value(std::string_view body, std::string_view name, bool* ok) {
  *ok = true;
  size_t start = 0;
  while (start <= body.size()) {
    const size_t amp = std::min(body.find('&', start), body.size());
    const std::string_view pair = body.substr(start, amp - start);
    start = amp + 1;
    const size_t eq = pair.find('=');
    if (pair.substr(0, eq) != name) continue;
    const std::string_view raw = eq == std::string_view::npos ? std::string_view() : pair.substr(eq + 1);
    std::string out;
    for (size_t i = 0; i < raw.size(); ++i) {
      if (raw[i] == '+') {
        out += ' ';
      } else if (raw[i] == '%') {
        const int hi = i + 2 < raw.size() ? hex_digit(raw[i + 1]) : -1;
        const int lo = hi >= 0 ? hex_digit(raw[i + 2]) : -1;
        if (lo < 0) {
          *ok = false;
          return std::nullopt;
        }
        out += static_cast<char>(hi * 16 + lo);
        i += 2;
      } else {
        out += raw[i];
      }
    }
    return out;
  }
  return std::nullopt;
}

const char* content_type(const std::filesystem::path& file) {
  const std::string ext = file.extension().string();
  if (ext == ".html") return "text/html; charset=utf-8";
  if (ext == ".js") return "text/javascript; charset=utf-8";
  if (ext == ".css") return "text/css; charset=utf-8";
  if (ext == ".png") return "image/png";
  if (ext == ".svg") return "image/svg+xml";
  if (ext == ".json") return "application/json";
  return "application/octet-stream";
}

// One name of the page's own folder: no path, no dot file, nothing to decode.
bool plain_file_name(std::string_view name) {
  if (name.empty() || name.front() == '.') return false;
  for (char c : name)
    if (!(std::isalnum(static_cast<unsigned char>(c)) || c == '.' || c == '_' || c == '-')) return false;
  return true;
}

}  // namespace

PageReply json_error(unsigned status, const std::string& message) {
  PageReply r;
  r.status = status;
  r.body = "{\"error\": " + daemon::json_string(message) + "}";
  return r;
}

PageRoutes::PageRoutes(std::string web_root, OriginPolicy policy, PageCommandAuth* auth,
                       CommandFn command, StatusFn status_json, WebCounters* counters)
    : web_root_(std::move(web_root)),
      policy_(std::move(policy)),
      auth_(auth),
      command_(std::move(command)),
      status_json_(std::move(status_json)),
      counters_(counters) {}

std::optional<PageReply> PageRoutes::refuse_foreign(const PageRequest& r) const {
  if (!policy_.host_allowed(r.host)) {
    ++counters_->origin_refused;
    if (!std::exchange(host_refusal_logged_, true))
      DF_LOG(Web, Warning) << "refused a request for Host '" << r.host << "' from " << r.peer
                           << " (a name pointed at this host from elsewhere?); further ones are only counted";
    return json_error(403, "Host '" + std::string(r.host) +
                               "' is not this monitor's: on loopback the page is served as localhost or "
                               "127.0.0.1 (or a name given with --allow-origin)");
  }
  if (r.origin && !policy_.origin_allowed(*r.origin, r.host)) {
    ++counters_->origin_refused;
    if (!std::exchange(origin_refusal_logged_, true))
      DF_LOG(Web, Warning) << "refused a request from the page of another site (Origin '" << *r.origin
                           << "') from " << r.peer << "; further ones are only counted";
    return json_error(403, "a request from another site's page (Origin '" + std::string(*r.origin) +
                               "') is refused; a proxy that changes the Host needs --allow-origin");
  }
  return std::nullopt;
}

std::optional<PageReply> PageRoutes::refuse_page(const PageRequest& r) const {
  if (auto refusal = refuse_foreign(r)) return refusal;
  const std::string_view path = r.target.substr(0, r.target.find('?'));
  if (path != "/ws") return json_error(404, "the page's WebSocket is /ws");
  if (r.method != "GET") return json_error(405, "a WebSocket opens with GET");
  return std::nullopt;
}

PageReply PageRoutes::answer(const PageRequest& r) const {
  if (auto refusal = refuse_foreign(r)) return *refusal;
  const std::string_view path = r.target.substr(0, r.target.find('?'));
  if (path == "/api/command") {
    if (r.method != "POST") return json_error(405, "POST only");
    return command(r);
  }
  if (r.method != "GET") return json_error(405, "GET only");
  if (path == "/api/status") {
    PageReply reply;
    reply.body = status_json_();
    return reply;
  }
  if (path == "/api/auth") return auth_settings();
  if (path == "/ws") return json_error(400, "/ws is the page's WebSocket");
  return file(path == "/" ? std::string_view("index.html") : path.substr(1));
}

PageReply PageRoutes::auth_settings() const {
  // The monitor's clock, so that the page signs with the time the monitor checks against even
  // when the browser's computer keeps another.
  const double skew_s = auth_ ? static_cast<double>(auth_->max_skew_us()) * 1e-6 : 0.0;
  PageReply reply;
  reply.body = std::string("{\"commands_need_key\": ") + (auth_ ? "true" : "false") +
               ", \"channel\": " + daemon::json_string(kPageCommandChannel) +
               ", \"max_clock_skew_s\": " + daemon::json_number(skew_s) +
               ", \"utime\": " + std::to_string(now_utime()) + "}";
  return reply;
}

PageReply PageRoutes::command(const PageRequest& r) const {
  // A page of another site that got past the origin check (an old browser) could still post a
  // form, but not with a header of its own: that needs a preflight, which is never approved.
  if (!r.page_header) return json_error(403, "missing the X-Depthfuse header (commands come from the page)");
  if (auth_) {
    const auto verdict = auth_->verify(r.body, r.signature ? r.signature->c_str() : nullptr, now_utime());
    if (!verdict.ok) {
      const std::string why = refusal_text(verdict.reason, auth_->max_skew_us());
      // The first refusal of each kind is logged; all are counted in the monitor's heartbeat.
      if (auth_->counters().dropped[static_cast<size_t>(verdict.reason)] == 1)
        DF_LOG(Web, Warning) << why << " (from " << r.peer << "; further ones are only counted)";
      PageReply reply;
      reply.status = 401;
      reply.body = "{\"error\": " + daemon::json_string(why) + ", \"refused\": " +
                   daemon::json_string(lcm::to_string(verdict.reason)) + "}";
      return reply;
    }
  }
  bool ok = true;
  const auto action = form_value(r.body, "action", &ok);
  if (!ok || !action || action->empty())
    return json_error(400, "no action (action=start|stop|pause|resume|new|checkpoint)");
  const auto argument = form_value(r.body, "argument", &ok);
  if (!ok) return json_error(400, "the argument is not form-encoded");
  if (action->size() > kMaxActionBytes) return json_error(400, "the action is too long");
  if (argument && argument->size() > kMaxArgumentBytes) return json_error(400, "the argument is too long");
  auto id = command_(*action, argument.value_or(""));
  if (!id) return json_error(400, id.status().message());
  ++counters_->commands_taken;
  PageReply reply;
  reply.status = 202;
  reply.body = "{\"command_id\": " + std::to_string(*id) + "}";
  return reply;
}

PageReply PageRoutes::file(std::string_view name) const {
  std::error_code ec;
  const std::filesystem::path path = std::filesystem::path(web_root_) / std::string(name);
  if (!plain_file_name(name) || !std::filesystem::is_regular_file(path, ec))
    return json_error(404, "no such page");
  PageReply reply;
  reply.content_type = content_type(path);
  reply.file = path.string();
  return reply;
}

}  // namespace depthfuse::monitor
