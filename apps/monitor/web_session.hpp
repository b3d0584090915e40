// The web server's connections (web_server.hpp), on its one thread: an HttpSession reads one
// request at a time within the request timeout and bounds, answers it from PageRoutes, and on a
// WebSocket upgrade hands its socket to a PageSession, which pushes what the server gives it in
// order from a bounded queue and reads only to answer pings and refuse what a page should not send.
// Internal to the monitor; Boost.Beast stays out of the other headers.
#pragma once

#include <boost/asio/ip/tcp.hpp>
#include <boost/beast/core/flat_buffer.hpp>
#include <boost/beast/core/tcp_stream.hpp>
#include <boost/beast/http/message.hpp>
#include <boost/beast/http/parser.hpp>
#include <boost/beast/http/serializer.hpp>
#include <boost/beast/http/string_body.hpp>
#include <boost/beast/websocket/stream.hpp>
#include <chrono>
#include <cstdint>
#include <deque>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include "map_store.hpp"
#include "page_routes.hpp"
#include "web_limits.hpp"

namespace depthfuse::monitor::web {

namespace beast = boost::beast;
namespace http = beast::http;
namespace websocket = beast::websocket;
using tcp = boost::asio::ip::tcp;
using Clock = std::chrono::steady_clock;
using Request = http::request<http::string_body>;

class PageSession;

class Session {
 public:
  virtual ~Session() = default;
  // Closes the socket at once, whatever the session is doing; it ends when its operations have.
  virtual void close() = 0;
  // Bytes from the client wait to be read: its request is arriving.
  virtual bool receiving() const = 0;
};

// What sessions ask of the server, on its thread.
class SessionHost {
 public:
  virtual ~SessionHost() = default;
  virtual const WebLimits& limits() const = 0;
  virtual WebCounters& counters() = 0;
  virtual const PageRoutes& routes() const = 0;
  virtual ConnectionTable& table() = 0;
  // `id` is now this session (a page took over a connection).
  virtual void track(uint64_t id, const std::shared_ptr<Session>& session) = 0;
  // A page's WebSocket is open: it gets pushes from now on.
  virtual void page_opened(const std::shared_ptr<PageSession>& page) = 0;
  // The connection `id` has ended.
  virtual void closed(uint64_t id) = 0;
};

class HttpSession final : public Session, public std::enable_shared_from_this<HttpSession> {
 public:
  HttpSession(tcp::socket socket, SessionHost& host, uint64_t id, std::string peer);
  ~HttpSession() override;
  void start() { read(); }
  void close() override;
  bool receiving() const override;

 private:
  void read();
  void on_read(beast::error_code ec);
  void answer(const Request& req);
  // The reply to a request that cannot be read (too large, malformed); the connection then closes.
  void refuse(unsigned status, const std::string& message);
  void upgrade(Request req);
  void send(PageReply reply, unsigned version, bool keep_alive);
  template <typename Body>
  void write(std::shared_ptr<http::response<Body>> res);
  template <typename Body>
  void write_some(std::shared_ptr<http::response<Body>> res,
                  std::shared_ptr<http::response_serializer<Body>> serializer);
  void on_written(beast::error_code ec, bool keep_alive);

  beast::tcp_stream stream_;
  beast::flat_buffer buffer_;
  std::optional<http::request_parser<http::string_body>> parser_;
  SessionHost& host_;
  uint64_t id_;
  std::string peer_;
  bool handed_over_ = false;  // to a PageSession: stream_ is no longer ours
};

class PageSession final : public Session, public std::enable_shared_from_this<PageSession> {
 public:
  PageSession(beast::tcp_stream stream, SessionHost& host, uint64_t id, std::string peer);
  ~PageSession() override;
  // The handshake's answer to `req` (an upgrade PageRoutes accepted).
  void start(Request req);
  void close() override;
  bool receiving() const override { return false; }

  // The server's pusher.
  uint64_t id() const { return id_; }
  const std::string& peer() const { return peer_; }
  bool open() const { return open_; }
  size_t queued_bytes() const { return queued_bytes_; }
  // A message has been on its way for longer than the limit: the page does not read.
  bool stalled(Clock::time_point now) const;
  // Queued after what is queued; false when that would pass the queue's bound (nothing queued).
  bool send(std::shared_ptr<const std::string> text);
  bool send(std::shared_ptr<const std::vector<uint8_t>> binary);

  MapStore::Cursor cursor;
  int64_t status_version = 0;

 private:
  struct Outgoing {
    std::shared_ptr<const std::string> text;
    std::shared_ptr<const std::vector<uint8_t>> binary;
    size_t size() const { return text ? text->size() : binary->size(); }
  };
  bool enqueue(Outgoing m);
  void write_next();
  void on_written(beast::error_code ec);
  void read();
  void on_read(beast::error_code ec);

  websocket::stream<beast::tcp_stream> ws_;
  beast::flat_buffer in_;
  Request request_;  // the upgrade, until the handshake is answered
  SessionHost& host_;
  uint64_t id_;
  std::string peer_;
  bool open_ = false;
  std::deque<Outgoing> queue_;
  size_t queued_bytes_ = 0;
  bool writing_ = false;
  Clock::time_point write_started_;
};

}  // namespace depthfuse::monitor::web
