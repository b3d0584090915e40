// Parsing and rewriting LCM URLs (see url.hpp).
#include "depthfuse/lcm/url.hpp"

#include <arpa/inet.h>
#include <netinet/in.h>

#include <cstdlib>

namespace depthfuse::lcm {

std::string udpm_url(int port) {
  return "udpm://" + std::string(kMulticastGroup) + ":" + std::to_string(port) +
         "?ttl=0&recv_buf_size=4194304";
}

std::string default_lcm_url() { return udpm_url(kDefaultPort); }

std::string url_with_ttl0(const LcmUrl& url) {
  if (url.provider != "udpm" || url.ttl == 0) return url.text;
  const auto q = url.text.find('?');
  if (q == std::string::npos) return url.text + "?ttl=0";
  std::string query = "&" + url.text.substr(q + 1) + "&";
  const auto at = query.find("&ttl=");
  if (at == std::string::npos) return url.text + "&ttl=0";
  const auto end = query.find('&', at + 1);
  query.replace(at, end - at, "&ttl=0");
  return url.text.substr(0, q + 1) + query.substr(1, query.size() - 2);
}

Result<LcmUrl> parse_lcm_url(const std::string& url) {
  LcmUrl out;
  out.text = url;
  const auto sep = url.find("://");
  if (sep == std::string::npos || sep == 0)
    return invalid_argument("LCM URL '" + url +
                            "' has no provider: expected e.g. " + default_lcm_url());
  out.provider = url.substr(0, sep);
  if (out.provider != "udpm") return out;

  std::string rest = url.substr(sep + 3);
  std::string query;
  if (const auto q = rest.find('?'); q != std::string::npos) {
    query = rest.substr(q + 1);
    rest = rest.substr(0, q);
  }
  std::string host = rest;
  out.port = kDefaultPort;
  if (const auto colon = rest.find(':'); colon != std::string::npos) {
    host = rest.substr(0, colon);
    const std::string port_text = rest.substr(colon + 1);
    char* end = nullptr;
    const long port = std::strtol(port_text.c_str(), &end, 10);
    if (port_text.empty() || *end != '\0' || port <= 0 || port > 65535)
      return invalid_argument("LCM URL '" + url + "': port '" + port_text +
                              "' is not a number in 1..65535");
    out.port = static_cast<int>(port);
  }
  out.multicast_group = host.empty() ? kMulticastGroup : host;
  in_addr addr{};
  if (inet_pton(AF_INET, out.multicast_group.c_str(), &addr) != 1)
    return invalid_argument("LCM URL '" + url + "': '" + out.multicast_group +
                            "' is not an IPv4 address");
  const uint32_t a = ntohl(addr.s_addr);
  if ((a >> 28) != 0xE)
    return invalid_argument("LCM URL '" + url + "': " + out.multicast_group +
                            " is not a multicast address (224.0.0.0/4)");

  size_t pos = 0;
  while (pos <= query.size() && !query.empty()) {
    const auto amp = query.find('&', pos);
    const std::string kv = query.substr(pos, amp == std::string::npos ? std::string::npos : amp - pos);
    const auto eq = kv.find('=');
    const std::string key = kv.substr(0, eq);
    const std::string value = eq == std::string::npos ? std::string() : kv.substr(eq + 1);
    char* end = nullptr;
    if (key == "ttl") {
      const long ttl = std::strtol(value.c_str(), &end, 10);
      if (value.empty() || *end != '\0' || ttl < 0 || ttl > 255)
        return invalid_argument("LCM URL '" + url + "': ttl '" + value + "' is not in 0..255");
      out.ttl = static_cast<int>(ttl);
    } else if (key == "recv_buf_size") {
      const long long size = std::strtoll(value.c_str(), &end, 10);
      if (value.empty() || *end != '\0' || size <= 0)
        return invalid_argument("LCM URL '" + url + "': recv_buf_size '" + value +
                                "' is not a positive number of bytes");
      out.recv_buf_size = size;
    }
    if (amp == std::string::npos) break;
    pos = amp + 1;
  }
  return out;
}

}  // namespace depthfuse::lcm
