// The operator's page over HTTP and WebSocket (civetweb, Debian's libcivetweb): the page's files
// from web_root, `GET /api/status` (the JSON of `depthfuse status --json`), `POST /api/command`
// (action=start|stop|pause|resume[&argument=NAME]: the same command_t as `depthfuse scan`; with a
// rig key only when the page signed it, page_auth.hpp), `GET /api/auth` (whether commands need
// the key, and the monitor's clock for the page's signatures) and the WebSocket /ws, which pushes the status and the map preview (MapStore) to every page.
// Requests run on civetweb's threads and pushes on a thread of this server's: neither ever waits
// on the monitor's LCM loop, and a slow page delays only the pushes.
#pragma once

#include <atomic>
#include <condition_variable>
#include <functional>
#include <map>
#include <memory>
#include <mutex>
#include <optional>
#include <string>
#include <thread>

#include "depthfuse/lcm/message_auth.hpp"
#include "depthfuse/status.hpp"
#include "map_store.hpp"
#include "page_auth.hpp"

struct mg_context;
struct mg_connection;

namespace depthfuse::monitor {

struct WebServerOptions {
  std::string listen;          // "ADDR:PORT"; PORT 0 takes a free one
  bool allow_remote = false;   // else ADDR must be loopback; another ADDR needs `key` too
  std::string web_root;        // index.html and the scripts
  // With a rig key, a command is carried out only when the page signed it with the key, signed
  // within max_skew_us of this host's clock; without one, every command from the page is.
  std::optional<lcm::RigKey> key;
  int64_t max_skew_us = 2000000;
};

class WebServer {
 public:
  // Takes a command for the fusion daemon (action name, argument) and returns its id, or an
  // error (unknown action).
  using CommandFn = std::function<Result<int64_t>(const std::string& action, const std::string& argument)>;

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

  int handle_status(mg_connection* conn);
  int handle_auth(mg_connection* conn);
  int handle_command(mg_connection* conn);
  void ws_ready(mg_connection* conn);
  void ws_closed(const mg_connection* conn);

 private:
  struct Client {
    MapStore::Cursor cursor;
    int64_t status_version = 0;
  };
  WebServer(const MapStore* store, CommandFn command) : store_(store), command_(std::move(command)) {}
  void push_loop();
  // Sends what the page lacks; false when the connection failed.
  bool push(mg_connection* conn, Client* client);

  const MapStore* store_;
  CommandFn command_;
  std::unique_ptr<PageCommandAuth> auth_;
  mg_context* ctx_ = nullptr;
  std::string url_;

  std::mutex status_mutex_;
  std::string status_json_ = "{}";
  int64_t status_version_ = 0;

  std::mutex clients_mutex_;  // held while pushing to a client, so that it cannot close meanwhile
  std::map<mg_connection*, Client> clients_;
  std::atomic<bool> stopping_{false};
  std::mutex wake_mutex_;
  std::condition_variable wake_;
  std::thread pusher_;
};

}  // namespace depthfuse::monitor
