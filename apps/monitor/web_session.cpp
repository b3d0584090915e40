// The web server's connections (see web_session.hpp).
#include "web_session.hpp"

#include <boost/asio/socket_base.hpp>
#include <boost/beast/http/file_body.hpp>
#include <boost/beast/http/read.hpp>
#include <boost/beast/http/write.hpp>
#include <tuple>
#include <utility>

#include "depthfuse/base/log.hpp"

DF_LOG_CATEGORY(Web)

namespace depthfuse::monitor::web {

namespace {

constexpr const char* kServerName = "depthfuse-monitor";
// How long a page's closing handshake may take; meanwhile what the client still sends is read
// and thrown away.
constexpr std::chrono::seconds kCloseTimeout{1};
// A page whose browser answers no ping for this long is gone (a browser answers at once).
constexpr std::chrono::seconds kPageIdleTimeout{20};

bool is_http_error(const beast::error_code& ec) {
  return ec.category() == http::make_error_code(http::error::bad_method).category();
}

PageRequest page_request(const Request& req, const std::string& peer) {
  PageRequest r;
  r.method = req.method_string();
  r.target = req.target();
  r.host = req[http::field::host];
  if (req.find(http::field::origin) != req.end()) r.origin = req[http::field::origin];
  r.page_header = req.find("X-Depthfuse") != req.end();
  if (req.find("X-Depthfuse-Signature") != req.end()) r.signature = std::string(req["X-Depthfuse-Signature"]);
  r.body = req.body();
  r.peer = peer;
  return r;
}

// Every answer: no other site may frame the page (its buttons command the rig), nor have the
// browser guess types.
template <typename Fields>
void common_headers(Fields* f, const std::string& content_type, bool cacheable) {
  f->set(http::field::server, kServerName);
  f->set(http::field::content_type, content_type);
  f->set(http::field::cache_control, cacheable ? "no-cache" : "no-store");
  f->set("X-Content-Type-Options", "nosniff");
  f->set("X-Frame-Options", "DENY");
  f->set("Content-Security-Policy", "frame-ancestors 'none'");
  f->set("Referrer-Policy", "no-referrer");
}

}  // namespace

// ------------------------------------------------------------------ HttpSession

HttpSession::HttpSession(tcp::socket socket, SessionHost& host, uint64_t id, std::string peer)
    : stream_(std::move(socket)),
      buffer_(kMaxRequestHeaderBytes + kMaxRequestBodyBytes),
      host_(host),
      id_(id),
      peer_(std::move(peer)) {}

HttpSession::~HttpSession() {
  if (!handed_over_) host_.closed(id_);
}

void HttpSession::close() {
  if (handed_over_) return;
  stream_.close();
}

bool HttpSession::receiving() const {
  if (handed_over_) return false;
  beast::error_code ec;
  return stream_.socket().available(ec) > 0 && !ec;
}

void HttpSession::read() {
  parser_.emplace();
  parser_->header_limit(kMaxRequestHeaderBytes);
  // A larger Content-Length is refused as soon as the header is read, before any of the body.
  parser_->body_limit(kMaxRequestBodyBytes);
  host_.table().waiting(id_, Clock::now());
  stream_.expires_after(host_.limits().request_timeout);
  http::async_read(stream_, buffer_, *parser_,
                   [self = shared_from_this()](beast::error_code ec, size_t) { self->on_read(ec); });
}

void HttpSession::on_read(beast::error_code ec) {
  if (ec == http::error::end_of_stream || ec == boost::asio::error::operation_aborted) return;
  if (ec == beast::error::timeout) {
    ++host_.counters().requests_timed_out;
    return;  // the stream closed the socket
  }
  if (ec == http::error::body_limit) {
    ++host_.counters().requests_too_large;
    return refuse(413, "a request body is at most " + std::to_string(kMaxRequestBodyBytes) + " bytes");
  }
  if (ec == http::error::header_limit || ec == http::error::buffer_overflow) {
    ++host_.counters().requests_too_large;
    return refuse(431, "request headers are at most " + std::to_string(kMaxRequestHeaderBytes) + " bytes");
  }
  if (ec) {
    if (is_http_error(ec)) return refuse(400, "not an HTTP request: " + ec.message());
    return;  // the connection failed
  }
  host_.table().busy(id_);
  Request req = parser_->release();
  if (websocket::is_upgrade(req)) return upgrade(std::move(req));
  answer(req);
}

void HttpSession::answer(const Request& req) {
  send(host_.routes().answer(page_request(req, peer_)), req.version(), req.keep_alive());
}

void HttpSession::refuse(unsigned status, const std::string& message) {
  send(json_error(status, message), 11, false);
}

void HttpSession::upgrade(Request req) {
  if (auto refusal = host_.routes().refuse_page(page_request(req, peer_)))
    return send(std::move(*refusal), req.version(), false);
  if (!host_.table().make_page(id_)) {
    ++host_.counters().pages_refused;
    const WebLimits& l = host_.limits();
    return send(json_error(503, "too many pages open (" + std::to_string(l.max_pages_per_address) +
                                    " per address, " + std::to_string(l.max_pages) +
                                    " in all); the page tries again by itself"),
                req.version(), false);
  }
  handed_over_ = true;
  auto page = std::make_shared<PageSession>(std::move(stream_), host_, id_, peer_);
  host_.track(id_, page);
  page->start(std::move(req));
}

void HttpSession::send(PageReply reply, unsigned version, bool keep_alive) {
  if (!reply.file.empty()) {
    http::file_body::value_type body;
    beast::error_code ec;
    body.open(reply.file.c_str(), beast::file_mode::scan, ec);
    if (!ec) {
      auto res = std::make_shared<http::response<http::file_body>>(
          std::piecewise_construct, std::make_tuple(std::move(body)), std::make_tuple(http::status::ok, version));
      common_headers(res.get(), reply.content_type, true);
      res->keep_alive(keep_alive);
      res->prepare_payload();
      return write(std::move(res));
    }
    reply = json_error(404, "no such page");
  }
  auto res = std::make_shared<http::response<http::string_body>>(static_cast<http::status>(reply.status), version);
  common_headers(res.get(), reply.content_type, false);
  if (reply.status == 503) res->set(http::field::retry_after, "2");
  res->body() = std::move(reply.body);
  res->keep_alive(keep_alive);
  res->prepare_payload();
  write(std::move(res));
}

template <typename Body>
void HttpSession::write(std::shared_ptr<http::response<Body>> res) {
  write_some(res, std::make_shared<http::response_serializer<Body>>(*res));
}

template <typename Body>
void HttpSession::write_some(std::shared_ptr<http::response<Body>> res,
                             std::shared_ptr<http::response_serializer<Body>> serializer) {
  // A client that takes nothing of the answer for this long ends the connection; a slow one that
  // keeps taking gets all of it.
  stream_.expires_after(host_.limits().send_timeout);
  http::async_write_some(stream_, *serializer,
                         [self = shared_from_this(), res, serializer](beast::error_code ec, size_t) {
                           if (!ec && !serializer->is_done()) return self->write_some(res, serializer);
                           self->on_written(ec, res->keep_alive());
                         });
}

void HttpSession::on_written(beast::error_code ec, bool keep_alive) {
  if (ec == beast::error::timeout) ++host_.counters().requests_timed_out;
  if (ec) return;
  if (keep_alive) return read();
  stream_.socket().shutdown(tcp::socket::shutdown_send, ec);
}

// ------------------------------------------------------------------ PageSession

PageSession::PageSession(beast::tcp_stream stream, SessionHost& host, uint64_t id, std::string peer)
    : ws_(std::move(stream)), host_(host), id_(id), peer_(std::move(peer)) {}

PageSession::~PageSession() { host_.closed(id_); }

void PageSession::start(Request req) {
  request_ = std::move(req);
  auto& lowest = beast::get_lowest_layer(ws_);
  lowest.expires_never();  // the WebSocket keeps its own time
  beast::error_code ec;
  // The kernel's share of what waits for this page; the queue here holds the rest, bounded.
  lowest.socket().set_option(boost::asio::socket_base::send_buffer_size(host_.limits().page_send_buffer_bytes), ec);
  websocket::stream_base::timeout timeouts{};
  timeouts.handshake_timeout = kCloseTimeout;
  timeouts.idle_timeout = kPageIdleTimeout;
  timeouts.keep_alive_pings = true;
  ws_.set_option(timeouts);
  ws_.set_option(websocket::stream_base::decorator(
      [](websocket::response_type& res) { res.set(http::field::server, kServerName); }));
  // Checked on each frame's header: a larger frame closes the connection before its payload is read.
  ws_.read_message_max(host_.limits().max_client_message_bytes);
  ws_.async_accept(request_, [self = shared_from_this()](beast::error_code ec) {
    self->request_ = {};
    if (ec) return;
    self->open_ = true;
    self->host_.page_opened(self);
    self->read();
  });
}

void PageSession::close() {
  open_ = false;
  beast::get_lowest_layer(ws_).close();
}

void PageSession::read() {
  ws_.async_read(in_, [self = shared_from_this()](beast::error_code ec, size_t) { self->on_read(ec); });
}

void PageSession::on_read(beast::error_code ec) {
  if (ec) {
    open_ = false;
    if (ec == websocket::error::message_too_big &&
        host_.counters().client_frames_refused.fetch_add(1) == 0)
      DF_LOG(Web, Warning) << "closed a page's WebSocket from " << peer_ << ": it sent a frame of more than "
                           << host_.limits().max_client_message_bytes
                           << " bytes (the page sends none); further ones are only counted";
    return;
  }
  in_.consume(in_.size());  // a few bytes a page has no reason to send: ignored
  read();
}

bool PageSession::stalled(Clock::time_point now) const {
  return writing_ && now - write_started_ > host_.limits().page_stall_timeout;
}

bool PageSession::send(std::shared_ptr<const std::string> text) { return enqueue({std::move(text), nullptr}); }

bool PageSession::send(std::shared_ptr<const std::vector<uint8_t>> binary) {
  return enqueue({nullptr, std::move(binary)});
}

bool PageSession::enqueue(Outgoing m) {
  if (!open_) return true;  // it is going: nothing to send it
  if (queued_bytes_ + m.size() > host_.limits().max_page_queue_bytes) return false;
  queued_bytes_ += m.size();
  queue_.push_back(std::move(m));
  if (!writing_) write_next();
  return true;
}

void PageSession::write_next() {
  const Outgoing& m = queue_.front();
  writing_ = true;
  write_started_ = Clock::now();
  ws_.binary(m.binary != nullptr);
  const auto buffer = m.text ? boost::asio::buffer(*m.text) : boost::asio::buffer(*m.binary);
  ws_.async_write(buffer, [self = shared_from_this()](beast::error_code ec, size_t) { self->on_written(ec); });
}

void PageSession::on_written(beast::error_code ec) {
  writing_ = false;
  queued_bytes_ -= queue_.front().size();
  queue_.pop_front();
  if (ec) {
    open_ = false;
    queue_.clear();
    queued_bytes_ = 0;
    return;
  }
  if (open_ && !queue_.empty()) write_next();
}

}  // namespace depthfuse::monitor::web
