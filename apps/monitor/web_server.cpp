// The operator's page server (see web_server.hpp).
#include "web_server.hpp"

#include <civetweb.h>

#include <chrono>
#include <cstring>
#include <filesystem>

#include "depthfuse/base/clock.hpp"
#include "depthfuse/base/log.hpp"
#include "depthfuse/daemon/status_json.hpp"

DF_LOG_CATEGORY(Web)

namespace depthfuse::monitor {

namespace {

constexpr size_t kMaxCommandBody = 4096;       // "action=start&argument=NAME" is far smaller
constexpr size_t kPushBytesPerRound = 1 << 20;  // per page and round, so that pages take turns
constexpr auto kPushPeriod = std::chrono::milliseconds(100);
constexpr unsigned kCivetwebWebsocketFeature = 16;  // mg_check_feature's bit for WebSocket

// Loopback unless the config says otherwise: the page's buttons command the scan.
bool loopback_host(const std::string& host) {
  return host == "localhost" || host == "[::1]" || host.rfind("127.", 0) == 0;
}

int reply(mg_connection* conn, int code, const char* type, const std::string& body) {
  mg_response_header_start(conn, code);
  mg_response_header_add(conn, "Content-Type", type, -1);
  mg_response_header_add(conn, "Cache-Control", "no-store", -1);
  mg_response_header_add(conn, "Content-Length", std::to_string(body.size()).c_str(), -1);
  mg_response_header_send(conn);
  mg_write(conn, body.data(), body.size());
  return code;
}

int json_error(mg_connection* conn, int code, const std::string& message) {
  return reply(conn, code, "application/json",
               "{\"error\": " + daemon::json_string(message) + "}");
}

WebServer* server_of(void* cbdata) { return static_cast<WebServer*>(cbdata); }

}  // namespace

Result<std::unique_ptr<WebServer>> WebServer::start(const WebServerOptions& options,
                                                    const MapStore* store, CommandFn command) {
  const size_t colon = options.listen.rfind(':');
  if (colon == std::string::npos || colon + 1 >= options.listen.size())
    return invalid_argument("monitor.http: '" + options.listen + "' must be ADDR:PORT, e.g. 127.0.0.1:8080");
  const std::string host = options.listen.substr(0, colon);
  if (!options.allow_remote && !loopback_host(host))
    return invalid_argument("monitor.http: '" + options.listen +
                            "' is not a loopback address; the page commands the scan: set "
                            "monitor.http_allow_remote = true to serve it to the network");
  // On loopback, only users of this host reach the page; beyond it, anyone on the network would
  // command the rig unless commands need the key.
  if (!loopback_host(host) && !options.key)
    return invalid_argument("monitor.http: serving the page on '" + options.listen +
                            "' needs the rig key (lcm.key_file): without it, anyone who reaches "
                            "the page can command the rig");
  std::error_code ec;
  if (!std::filesystem::is_regular_file(std::filesystem::path(options.web_root) / "index.html", ec))
    return not_found("the operator's page is not in '" + options.web_root +
                     "' (no index.html): set monitor.web_root or --web-root");
  mg_init_library(0);
  if (!mg_check_feature(kCivetwebWebsocketFeature))
    return unavailable("this civetweb library was built without WebSocket support");

  // civetweb takes "localhost" literally as a name it cannot bind: give it the address.
  const std::string listen = (host == "localhost" ? "127.0.0.1" : host) + options.listen.substr(colon);
  const char* mg_options[] = {"listening_ports", listen.c_str(),
                              "document_root", options.web_root.c_str(),
                              "enable_directory_listing", "no",
                              "num_threads", "8",
                              "request_timeout_ms", "10000",
                              "enable_keep_alive", "no",
                              "max_request_size", "16384",
                              nullptr};
  std::unique_ptr<WebServer> server(new WebServer(store, std::move(command)));
  if (options.key) server->auth_ = std::make_unique<PageCommandAuth>(*options.key, options.max_skew_us);
  mg_callbacks callbacks{};
  char error_text[256] = "";
  mg_init_data init{};
  init.callbacks = &callbacks;
  init.user_data = server.get();
  init.configuration_options = mg_options;
  mg_error_data error{};
  error.text = error_text;
  error.text_buffer_size = sizeof(error_text);
  server->ctx_ = mg_start2(&init, &error);
  if (!server->ctx_)
    return unavailable("cannot serve the operator's page on " + options.listen + ": " +
                       (error_text[0] ? error_text : "civetweb failed to start"));
  mg_server_port ports[4];
  const int n = mg_get_server_ports(server->ctx_, 4, ports);
  const int port = n > 0 ? ports[0].port : 0;
  server->url_ = "http://" + (host.empty() ? std::string("0.0.0.0") : host) + ":" +
                 std::to_string(port) + "/";

  mg_set_request_handler(server->ctx_, "/api/status$",
                         [](mg_connection* c, void* d) { return server_of(d)->handle_status(c); },
                         server.get());
  mg_set_request_handler(server->ctx_, "/api/auth$",
                         [](mg_connection* c, void* d) { return server_of(d)->handle_auth(c); },
                         server.get());
  mg_set_request_handler(server->ctx_, "/api/command$",
                         [](mg_connection* c, void* d) { return server_of(d)->handle_command(c); },
                         server.get());
  mg_set_websocket_handler(
      server->ctx_, "/ws$", [](const mg_connection*, void*) { return 0; },
      [](mg_connection* c, void* d) { server_of(d)->ws_ready(c); },
      [](mg_connection*, int, char*, size_t, void*) { return 1; },  // pages only listen
      [](const mg_connection* c, void* d) { server_of(d)->ws_closed(c); }, server.get());
  server->pusher_ = std::thread([s = server.get()] { s->push_loop(); });
  return server;
}

WebServer::~WebServer() {
  stopping_ = true;
  wake_.notify_all();
  if (pusher_.joinable()) pusher_.join();
  if (ctx_) mg_stop(ctx_);
}

void WebServer::set_status(std::string json) {
  {
    std::lock_guard<std::mutex> lock(status_mutex_);
    status_json_ = std::move(json);
    ++status_version_;
  }
  wake_.notify_all();
}

int WebServer::handle_status(mg_connection* conn) {
  const mg_request_info* req = mg_get_request_info(conn);
  if (std::strcmp(req->request_method, "GET") != 0) return json_error(conn, 405, "GET only");
  std::string body;
  {
    std::lock_guard<std::mutex> lock(status_mutex_);
    body = status_json_;
  }
  return reply(conn, 200, "application/json", body);
}

int WebServer::handle_auth(mg_connection* conn) {
  const mg_request_info* req = mg_get_request_info(conn);
  if (std::strcmp(req->request_method, "GET") != 0) return json_error(conn, 405, "GET only");
  // The monitor's clock, so that the page signs with the time the monitor checks against even
  // when the browser's computer keeps another.
  const double skew_s = auth_ ? static_cast<double>(auth_->max_skew_us()) * 1e-6 : 0.0;
  return reply(conn, 200, "application/json",
               std::string("{\"commands_need_key\": ") + (auth_ ? "true" : "false") +
                   ", \"channel\": " + daemon::json_string(kPageCommandChannel) +
                   ", \"max_clock_skew_s\": " + daemon::json_number(skew_s) + ", \"utime\": " +
                   std::to_string(now_utime()) + "}");
}

int WebServer::handle_command(mg_connection* conn) {
  const mg_request_info* req = mg_get_request_info(conn);
  if (std::strcmp(req->request_method, "POST") != 0) return json_error(conn, 405, "POST only");
  // A page of another site can post a form to this address, but not with a header of its own
  // (that needs a CORS preflight, which is never answered): the header is what makes it ours.
  if (!mg_get_header(conn, "X-Depthfuse"))
    return json_error(conn, 403, "missing the X-Depthfuse header (commands come from the page)");
  if (req->content_length < 0 || static_cast<size_t>(req->content_length) > kMaxCommandBody)
    return json_error(conn, 413, "a command is at most " + std::to_string(kMaxCommandBody) + " bytes");
  std::string body(static_cast<size_t>(req->content_length), '\0');
  size_t got = 0;
  while (got < body.size()) {
    const int r = mg_read(conn, body.data() + got, body.size() - got);
    if (r <= 0) return json_error(conn, 400, "the request body ended early");
    got += static_cast<size_t>(r);
  }
  if (auth_) {
    const auto verdict = auth_->verify(body, mg_get_header(conn, "X-Depthfuse-Signature"), now_utime());
    if (!verdict.ok) {
      const std::string why = refusal_text(verdict.reason, auth_->max_skew_us());
      // The first refusal of each kind is logged; all are counted in the monitor's heartbeat.
      if (auth_->counters().dropped[static_cast<size_t>(verdict.reason)] == 1)
        DF_LOG(Web, Warning) << why << " (from " << req->remote_addr << "; further ones are only counted)";
      return reply(conn, 401, "application/json",
                   "{\"error\": " + daemon::json_string(why) + ", \"refused\": " +
                       daemon::json_string(lcm::to_string(verdict.reason)) + "}");
    }
  }
  char action[32] = "", argument[128] = "";
  if (mg_get_var(body.data(), body.size(), "action", action, sizeof(action)) < 0)
    return json_error(conn, 400, "no action (action=start|stop|pause|resume|new|checkpoint)");
  if (mg_get_var(body.data(), body.size(), "argument", argument, sizeof(argument)) < -1)
    return json_error(conn, 400, "the argument is too long");
  auto id = command_(action, argument);
  if (!id) return json_error(conn, 400, id.status().message());
  return reply(conn, 202, "application/json", "{\"command_id\": " + std::to_string(*id) + "}");
}

void WebServer::ws_ready(mg_connection* conn) {
  {
    std::lock_guard<std::mutex> lock(clients_mutex_);
    clients_[conn] = Client{};
  }
  wake_.notify_all();
}

void WebServer::ws_closed(const mg_connection* conn) {
  std::lock_guard<std::mutex> lock(clients_mutex_);
  clients_.erase(const_cast<mg_connection*>(conn));
}

bool WebServer::push(mg_connection* conn, Client* client) {
  std::vector<std::string> text;
  std::vector<std::shared_ptr<const std::vector<uint8_t>>> chunks;
  {
    std::lock_guard<std::mutex> lock(status_mutex_);
    if (client->status_version != status_version_) {
      text.push_back("{\"type\": \"status\", \"status\": " + status_json_ + "}");
      client->status_version = status_version_;
    }
  }
  store_->changes(&client->cursor, kPushBytesPerRound, &text, &chunks);
  for (const auto& t : text)
    if (mg_websocket_write(conn, MG_WEBSOCKET_OPCODE_TEXT, t.data(), t.size()) <= 0) return false;
  for (const auto& c : chunks)
    if (mg_websocket_write(conn, MG_WEBSOCKET_OPCODE_BINARY, reinterpret_cast<const char*>(c->data()),
                           c->size()) <= 0)
      return false;
  return true;
}

void WebServer::push_loop() {
  while (!stopping_) {
    {
      std::unique_lock<std::mutex> lock(wake_mutex_);
      wake_.wait_for(lock, kPushPeriod);
    }
    if (stopping_) break;
    std::lock_guard<std::mutex> lock(clients_mutex_);
    for (auto& [conn, client] : clients_)
      if (!push(conn, &client)) DF_LOG(Web, Info) << "a page's connection failed; civetweb closes it";
  }
}

}  // namespace depthfuse::monitor
