// The operator's page server (see web_server.hpp): the listening socket, the connection table, the
// pushes to pages, and the one thread that runs them all.
#include "web_server.hpp"

#include <boost/asio/io_context.hpp>
#include <boost/asio/ip/address.hpp>
#include <boost/asio/post.hpp>
#include <boost/asio/steady_timer.hpp>
#include <cstdlib>
#include <filesystem>
#include <map>
#include <mutex>
#include <optional>
#include <thread>
#include <vector>

#include "depthfuse/base/log.hpp"
#include "web_session.hpp"

DF_LOG_CATEGORY(Web)

namespace depthfuse::monitor {

namespace asio = boost::asio;
using web::Clock;
using web::PageSession;
using web::Session;
using web::tcp;
using error_code = boost::system::error_code;

namespace {

constexpr size_t kPushBytesPerRound = 1 << 20;  // a page gets more only once it holds less than this
constexpr auto kPushPeriod = std::chrono::milliseconds(100);
constexpr auto kAcceptRetry = std::chrono::milliseconds(100);

}  // namespace

class WebServer::Core final : public web::SessionHost {
 public:
  Core(const WebServerOptions& options, bool loopback, const MapStore* store, PageCommandAuth* auth,
       CommandFn command, WebCounters* counters)
      : limits_(options.limits),
        counters_(counters),
        store_(store),
        table_(options.limits),
        routes_(options.web_root, OriginPolicy(loopback, options.allowed_origins), auth, std::move(command),
                [this] { return status_json(); }, counters) {}

  ~Core() override {
    io_->stop();
    if (thread_.joinable()) thread_.join();
    // The handlers still pending hold the sessions, which report to this object as they end: the
    // io_context goes (and with it they) while everything else is whole.
    acceptor_.reset();
    push_timer_.reset();
    accept_retry_.reset();
    io_.reset();
  }

  // Listens on `endpoint`; the port it got.
  Result<int> listen(const tcp::endpoint& endpoint) {
    acceptor_.emplace(*io_);
    error_code ec;
    acceptor_->open(endpoint.protocol(), ec);
    if (!ec) acceptor_->set_option(asio::socket_base::reuse_address(true), ec);
    if (!ec) acceptor_->bind(endpoint, ec);
    if (!ec) acceptor_->listen(asio::socket_base::max_listen_connections, ec);
    if (ec) return unavailable(ec.message());
    return static_cast<int>(acceptor_->local_endpoint().port());
  }

  void run() {
    push_timer_.emplace(*io_);
    accept_retry_.emplace(*io_);
    accept();
    schedule_push();
    thread_ = std::thread([this] {
      try {
        io_->run();
      } catch (const std::exception& e) {
        DF_LOG(Web, Error) << "the operator's page server stopped: " << e.what();
      }
    });
  }

  void set_status(std::string json) {
    {
      std::lock_guard<std::mutex> lock(status_mutex_);
      status_json_ = std::move(json);
      ++status_version_;
    }
    asio::post(*io_, [this] { push(); });
  }

  // web::SessionHost
  const WebLimits& limits() const override { return limits_; }
  WebCounters& counters() override { return *counters_; }
  const PageRoutes& routes() const override { return routes_; }
  ConnectionTable& table() override { return table_; }
  void track(uint64_t id, const std::shared_ptr<Session>& session) override { sessions_[id] = session; }
  void page_opened(const std::shared_ptr<PageSession>& page) override {
    pages_[page->id()] = page;
    push();
  }
  void closed(uint64_t id) override {
    table_.remove(id);
    sessions_.erase(id);
    pages_.erase(id);
  }

 private:
  std::string status_json() {
    std::lock_guard<std::mutex> lock(status_mutex_);
    return status_json_;
  }

  void accept() {
    acceptor_->async_accept([this](error_code ec, tcp::socket socket) { on_accept(ec, std::move(socket)); });
  }

  void on_accept(error_code ec, tcp::socket socket) {
    if (ec == asio::error::operation_aborted) return;
    if (ec) {
      // Out of descriptors (or memory): try again shortly rather than spin.
      if (!accept_failure_logged_) {
        accept_failure_logged_ = true;
        DF_LOG(Web, Warning) << "cannot accept a connection: " << ec.message();
      }
      accept_retry_->expires_after(kAcceptRetry);
      accept_retry_->async_wait([this](error_code e) {
        if (!e) accept();
      });
      return;
    }
    error_code peer_ec;
    const tcp::endpoint peer = socket.remote_endpoint(peer_ec);
    if (!peer_ec) admit(std::move(socket), peer.address().to_string());
    accept();
  }

  void admit(tcp::socket socket, const std::string& peer) {
    const uint64_t id = ++next_id_;
    const auto admission = table_.admit(id, peer, Clock::now(), [this](uint64_t candidate) {
      const auto it = sessions_.find(candidate);
      const auto session = it == sessions_.end() ? nullptr : it->second.lock();
      return !session || !session->receiving();
    });
    if (admission.evict) {
      ++counters_->connections_evicted;
      const auto it = sessions_.find(admission.evict);
      if (it != sessions_.end()) {
        const auto evicted = it->second.lock();
        sessions_.erase(it);
        if (evicted) evicted->close();
      }
    }
    if (!admission.admitted) {
      if (counters_->connections_refused.fetch_add(1) == 0)
        DF_LOG(Web, Warning) << "refused a connection from " << peer << ": " << table_.size()
                             << " connections are busy (further refusals are only counted)";
      error_code ignored;
      socket.close(ignored);
      return;
    }
    auto session = std::make_shared<web::HttpSession>(std::move(socket), *this, id, peer);
    sessions_[id] = session;
    session->start();
  }

  void schedule_push() {
    push_timer_->expires_after(kPushPeriod);
    push_timer_->async_wait([this](error_code ec) {
      if (ec) return;
      push();
      schedule_push();
    });
  }

  // What each page lacks, to every page that has taken what it was sent before.
  void push() {
    const auto now = Clock::now();
    std::shared_ptr<const std::string> status;
    int64_t version = 0;
    {
      std::lock_guard<std::mutex> lock(status_mutex_);
      if (status_message_version_ != status_version_) {
        status_message_ =
            std::make_shared<const std::string>("{\"type\": \"status\", \"status\": " + status_json_ + "}");
        status_message_version_ = status_version_;
      }
      status = status_message_;
      version = status_version_;
    }
    std::vector<std::string> text;
    std::vector<std::shared_ptr<const std::vector<uint8_t>>> chunks;
    for (auto it = pages_.begin(); it != pages_.end();) {
      const auto page = it->second.lock();
      if (!page || !page->open()) {
        it = pages_.erase(it);
        continue;
      }
      bool ok = !page->stalled(now);
      if (ok && page->queued_bytes() < kPushBytesPerRound) {
        if (page->status_version != version && status) ok = page->send(status);
        page->status_version = version;
        text.clear();
        chunks.clear();
        store_->changes(&page->cursor, kPushBytesPerRound, &text, &chunks);
        for (auto& t : text) ok = ok && page->send(std::make_shared<const std::string>(std::move(t)));
        for (auto& c : chunks) ok = ok && page->send(c);
      }
      if (ok) {
        ++it;
        continue;
      }
      if (counters_->pages_dropped.fetch_add(1) == 0)
        DF_LOG(Web, Warning) << "dropped a page at " << page->peer() << ": it took nothing for "
                             << limits_.page_stall_timeout.count() << " ms (further drops are only counted)";
      it = pages_.erase(it);
      page->close();
    }
  }

  WebLimits limits_;
  WebCounters* counters_;
  const MapStore* store_;
  ConnectionTable table_;
  PageRoutes routes_;

  std::unique_ptr<asio::io_context> io_ = std::make_unique<asio::io_context>(1);
  std::optional<tcp::acceptor> acceptor_;
  std::optional<asio::steady_timer> push_timer_, accept_retry_;
  std::thread thread_;
  uint64_t next_id_ = 0;
  bool accept_failure_logged_ = false;
  std::map<uint64_t, std::weak_ptr<Session>> sessions_;
  std::map<uint64_t, std::weak_ptr<PageSession>> pages_;

  std::mutex status_mutex_;  // the LCM thread sets the status
  std::string status_json_ = "{}";
  int64_t status_version_ = 0;
  std::shared_ptr<const std::string> status_message_;
  int64_t status_message_version_ = 0;
};

Result<std::unique_ptr<WebServer>> WebServer::start(const WebServerOptions& options,
                                                    const MapStore* store, CommandFn command) {
  const size_t colon = options.listen.rfind(':');
  if (colon == std::string::npos || colon + 1 >= options.listen.size())
    return invalid_argument("monitor.http: '" + options.listen + "' must be ADDR:PORT, e.g. 127.0.0.1:8080");
  const std::string host = options.listen.substr(0, colon);
  const bool loopback = is_loopback_host(host);
  if (!options.allow_remote && !loopback)
    return invalid_argument("monitor.http: '" + options.listen +
                            "' is not a loopback address; the page commands the scan: set "
                            "monitor.http_allow_remote = true to serve it to the network");
  // On loopback, only users of this host reach the page; beyond it, anyone on the network would
  // command the rig unless commands need the key.
  if (!loopback && !options.key)
    return invalid_argument("monitor.http: serving the page on '" + options.listen +
                            "' needs the rig key (lcm.key_file): without it, anyone who reaches "
                            "the page can command the rig");
  std::error_code fs_ec;
  if (!std::filesystem::is_regular_file(std::filesystem::path(options.web_root) / "index.html", fs_ec))
    return not_found("the operator's page is not in '" + options.web_root +
                     "' (no index.html): set monitor.web_root or --web-root");
  const std::string port_text = options.listen.substr(colon + 1);
  char* end = nullptr;
  const long port = std::strtol(port_text.c_str(), &end, 10);
  if (*end != '\0' || port < 0 || port > 65535)
    return invalid_argument("monitor.http: '" + options.listen + "': the port must be 0 to 65535");
  std::string address_text = host.empty() ? "0.0.0.0" : host == "localhost" ? "127.0.0.1" : host;
  if (address_text.size() > 2 && address_text.front() == '[' && address_text.back() == ']')
    address_text = address_text.substr(1, address_text.size() - 2);
  error_code ec;
  const auto address = asio::ip::make_address(address_text, ec);
  if (ec)
    return invalid_argument("monitor.http: '" + options.listen + "': '" + host +
                            "' is not an IP address (nor localhost)");

  std::unique_ptr<WebServer> server(new WebServer());
  if (options.key) server->auth_ = std::make_unique<PageCommandAuth>(*options.key, options.max_skew_us);
  server->core_ = std::make_unique<Core>(options, loopback, store, server->auth_.get(), std::move(command),
                                         &server->counters_);
  auto bound = server->core_->listen(tcp::endpoint(address, static_cast<unsigned short>(port)));
  if (!bound)
    return unavailable("cannot serve the operator's page on " + options.listen + ": " +
                       bound.status().message());
  server->url_ =
      "http://" + (host.empty() ? std::string("0.0.0.0") : host) + ":" + std::to_string(*bound) + "/";
  server->core_->run();
  return server;
}

WebServer::~WebServer() = default;

void WebServer::set_status(std::string json) { core_->set_status(std::move(json)); }

}  // namespace depthfuse::monitor
