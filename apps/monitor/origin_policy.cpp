// Which requests come from the operator's page (see origin_policy.hpp).
#include "origin_policy.hpp"

#include <arpa/inet.h>

#include <algorithm>
#include <cctype>

namespace depthfuse::monitor {

namespace {

std::string lower(std::string_view s) {
  std::string out(s);
  std::transform(out.begin(), out.end(), out.begin(), [](unsigned char c) { return std::tolower(c); });
  return out;
}

// "[::1]:8080" -> "[::1]", "127.0.0.1:8080" -> "127.0.0.1", "localhost" -> "localhost".
std::string_view without_port(std::string_view host) {
  if (!host.empty() && host.front() == '[') {
    const size_t close = host.find(']');
    return close == std::string_view::npos ? host : host.substr(0, close + 1);
  }
  const size_t colon = host.find(':');
  return colon == std::string_view::npos ? host : host.substr(0, colon);
}

// The part after "scheme://" of an origin.
std::string_view authority(std::string_view origin) {
  const size_t at = origin.find("://");
  return at == std::string_view::npos ? std::string_view() : origin.substr(at + 3);
}

}  // namespace

bool is_loopback_host(std::string_view host_without_port) {
  const std::string h = lower(host_without_port);
  if (h == "localhost" || h == "[::1]") return true;
  in_addr addr{};
  // An address literal, not a name that starts with "127." ("127.0.0.1.example.com").
  return inet_pton(AF_INET, h.c_str(), &addr) == 1 && (ntohl(addr.s_addr) >> 24) == 127;
}

bool OriginPolicy::host_allowed(std::string_view host) const {
  if (host.empty() || !loopback_only_) return true;
  if (is_loopback_host(without_port(host))) return true;
  const std::string h = lower(host);
  return std::any_of(allowed_.begin(), allowed_.end(),
                     [&](const std::string& o) { return authority(o) == h; });
}

bool OriginPolicy::origin_allowed(std::string_view origin, std::string_view host) const {
  const std::string o = lower(origin);
  if (!host.empty()) {
    const std::string h = lower(host);
    if (o == "http://" + h || o == "https://" + h) return true;
  }
  return std::find(allowed_.begin(), allowed_.end(), o) != allowed_.end();
}

Result<std::vector<std::string>> parse_origins(std::string_view list) {
  std::vector<std::string> out;
  size_t start = 0;
  while (start <= list.size()) {
    const size_t comma = std::min(list.find(',', start), list.size());
    std::string_view item = list.substr(start, comma - start);
    start = comma + 1;
    while (!item.empty() && std::isspace(static_cast<unsigned char>(item.front()))) item.remove_prefix(1);
    while (!item.empty() && std::isspace(static_cast<unsigned char>(item.back()))) item.remove_suffix(1);
    if (item.empty()) continue;
    std::string o = lower(item);
    if (o.back() == '/') o.pop_back();
    const bool scheme_ok = o.rfind("http://", 0) == 0 || o.rfind("https://", 0) == 0;
    const std::string_view auth = authority(o);
    const std::string_view name = without_port(auth);
    const std::string_view port = auth.substr(name.size());
    const bool port_ok = port.empty() || (port.size() > 1 && port.front() == ':' &&
                                          std::all_of(port.begin() + 1, port.end(), [](char c) {
                                            return std::isdigit(static_cast<unsigned char>(c));
                                          }));
    if (!scheme_ok || name.empty() || auth.find_first_of("/?#@ ") != std::string_view::npos || !port_ok)
      return invalid_argument("'" + std::string(item) +
                              "' is not an origin: scheme://host[:port] with scheme http or https, "
                              "e.g. https://rig.example");
    out.push_back(std::move(o));
  }
  return out;
}

}  // namespace depthfuse::monitor
