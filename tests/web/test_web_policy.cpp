// The web server's decisions without sockets: which Host and Origin are the page's
// (origin_policy.hpp) and which connection makes room when the table is full (web_limits.hpp).
// The real server against real clients is test_web_hostile.py.
#include <gtest/gtest.h>

#include <set>

#include "origin_policy.hpp"
#include "web_limits.hpp"

namespace depthfuse::monitor {
namespace {

TEST(OriginPolicy, LoopbackHostsOnlyOnLoopback) {
  const OriginPolicy local(true, {});
  for (const char* host : {"127.0.0.1:8080", "localhost:9000", "LOCALHOST", "[::1]:8080", "127.1.2.3", ""})
    EXPECT_TRUE(local.host_allowed(host)) << host;
  // Names an attacker points at 127.0.0.1 (DNS rebinding), however they start.
  for (const char* host : {"rebind.example:8080", "127.0.0.1.rebind.example:8080", "localhost.example",
                           "10.0.0.5:8080", "[::2]:8080", "127.0.0.256"})
    EXPECT_FALSE(local.host_allowed(host)) << host;
  const OriginPolicy proxied(true, {"https://rig.example"});
  EXPECT_TRUE(proxied.host_allowed("rig.example"));
  EXPECT_FALSE(proxied.host_allowed("rig.example:8443"));
  // Served to the network (with a key), the rig's names are not known: any Host.
  EXPECT_TRUE(OriginPolicy(false, {}).host_allowed("rig.local:8080"));
}

TEST(OriginPolicy, OnlyThePagesOwnOriginOrAConfiguredOne) {
  const OriginPolicy p(true, {"https://rig.example"});
  EXPECT_TRUE(p.origin_allowed("http://127.0.0.1:8080", "127.0.0.1:8080"));
  EXPECT_TRUE(p.origin_allowed("HTTP://LocalHost:8080", "localhost:8080"));
  EXPECT_TRUE(p.origin_allowed("https://127.0.0.1:8443", "127.0.0.1:8443"));  // a TLS proxy keeping Host
  EXPECT_TRUE(p.origin_allowed("https://rig.example", "127.0.0.1:8080"));     // one rewriting it
  for (const char* origin : {"http://127.0.0.1:8081", "http://evil.example", "null", "",
                             "http://127.0.0.1:8080/", "ws://127.0.0.1:8080", "http://127.0.0.1"})
    EXPECT_FALSE(p.origin_allowed(origin, "127.0.0.1:8080")) << origin;
  EXPECT_FALSE(p.origin_allowed("http://127.0.0.1:8080", ""));
}

TEST(OriginPolicy, ParsesAndRefusesOrigins) {
  auto ok = parse_origins(" https://Rig.Example/ , http://10.0.0.5:8080,,");
  ASSERT_TRUE(ok.is_ok()) << ok.status().to_string();
  EXPECT_EQ(*ok, (std::vector<std::string>{"https://rig.example", "http://10.0.0.5:8080"}));
  EXPECT_TRUE(parse_origins("")->empty());
  for (const char* bad : {"rig.example", "ftp://rig.example", "https://", "https://rig.example/page",
                          "https://user@rig.example", "https://rig.example:80x", "https://rig.example:"}) {
    auto r = parse_origins(bad);
    ASSERT_FALSE(r.is_ok()) << bad;
    EXPECT_NE(r.status().message().find("is not an origin"), std::string::npos) << r.status().message();
  }
}

using Clock = ConnectionTable::Clock;

TEST(ConnectionTable, TheLongestWaitingIdleConnectionMakesRoom) {
  WebLimits limits;
  limits.max_connections = 4;
  limits.max_connections_per_address = 3;
  ConnectionTable table(limits);
  const auto t0 = Clock::now();
  const auto any = [](uint64_t) { return true; };
  const auto at = [&](int ms) { return t0 + std::chrono::milliseconds(ms); };
  EXPECT_TRUE(table.admit(1, "a", at(0), any).admitted);
  EXPECT_TRUE(table.admit(2, "a", at(1), any).admitted);
  EXPECT_TRUE(table.admit(3, "a", at(2), any).admitted);
  table.busy(1);  // answering: never evicted
  // The address's share is full: its longest-waiting idle connection (2) makes room.
  auto a = table.admit(4, "a", at(3), any);
  EXPECT_TRUE(a.admitted);
  EXPECT_EQ(a.evict, 2u);
  // One whose request is arriving is passed over.
  a = table.admit(5, "a", at(4), [](uint64_t id) { return id != 3; });
  EXPECT_EQ(a.evict, 4u);
  // Another address is not held back by "a"'s share, but the table is full (1, 3, 5, 6).
  EXPECT_TRUE(table.admit(6, "b", at(5), any).admitted);
  EXPECT_EQ(table.size(), 4u);
  a = table.admit(7, "c", at(6), any);
  EXPECT_TRUE(a.admitted);
  EXPECT_EQ(a.evict, 3u);  // the longest waiting in all
  // When nothing may make room, the newcomer is refused.
  table.busy(5);
  table.busy(6);
  table.busy(7);
  a = table.admit(8, "c", at(7), any);
  EXPECT_FALSE(a.admitted);
  EXPECT_EQ(a.evict, 0u);
  // A kept-alive connection waits again from its last answer.
  table.waiting(6, at(8));
  EXPECT_EQ(table.admit(9, "d", at(9), any).evict, 6u);
}

TEST(ConnectionTable, PagesAreBoundedAndNeverEvicted) {
  WebLimits limits;
  limits.max_connections = 8;
  limits.max_connections_per_address = 8;
  limits.max_pages = 3;
  limits.max_pages_per_address = 2;
  ConnectionTable table(limits);
  const auto now = Clock::now();
  const auto any = [](uint64_t) { return true; };
  for (uint64_t id = 1; id <= 4; ++id) table.admit(id, id <= 3 ? "a" : "b", now, any);
  EXPECT_TRUE(table.make_page(1));
  EXPECT_TRUE(table.make_page(2));
  EXPECT_FALSE(table.make_page(3));  // "a" has two
  EXPECT_TRUE(table.make_page(4));
  EXPECT_EQ(table.pages(), 3u);
  table.remove(1);
  EXPECT_TRUE(table.make_page(3));
  table.remove(3);
  table.remove(3);  // twice: ignored
  EXPECT_EQ(table.pages(), 2u);
  // Pages never make room: with only pages and busy connections, a newcomer is refused.
  for (uint64_t id = 10; id < 16; ++id) ASSERT_TRUE(table.admit(id, "c", now, any).admitted);
  for (uint64_t id = 10; id < 16; ++id) table.busy(id);
  EXPECT_FALSE(table.admit(20, "c", now, any).admitted);
}

}  // namespace
}  // namespace depthfuse::monitor
