// Opening LCM: URL checks, the host diagnosis (route, receive buffer), a real udpm round trip on
// loopback, and the explanation a daemon gives when multicast has no route.
#include <gtest/gtest.h>

#include <thread>

#include "depthfuse/depth_frame_t.hpp"
#include "depthfuse/heartbeat_t.hpp"
#include "depthfuse/lcm/channels.hpp"
#include "depthfuse/lcm/codec.hpp"
#include "depthfuse/lcm/frame_codec.hpp"
#include "lcm_test_util.hpp"

namespace depthfuse {
namespace {

using namespace depthfuse::testing;

TEST(LcmUrl, ParsesUdpm) {
  auto u = lcm::parse_lcm_url("udpm://239.255.76.67:7667?ttl=0&recv_buf_size=4194304");
  ASSERT_TRUE(u.is_ok()) << u.status().to_string();
  EXPECT_EQ(u->provider, "udpm");
  EXPECT_EQ(u->multicast_group, "239.255.76.67");
  EXPECT_EQ(u->port, 7667);
  EXPECT_EQ(u->ttl, 0);
  EXPECT_EQ(u->recv_buf_size, 4194304);
  auto d = lcm::parse_lcm_url("udpm://");
  ASSERT_TRUE(d.is_ok());
  EXPECT_EQ(d->multicast_group, "239.255.76.67");
  EXPECT_EQ(d->recv_buf_size, -1);
  EXPECT_TRUE(lcm::parse_lcm_url("memq://").is_ok());
}

TEST(LcmUrl, RejectsBadUrlsWithReasons) {
  for (const char* bad : {"239.255.76.67:7667", "udpm://239.255.76.67:99999", "udpm://10.0.0.1:7667",
                          "udpm://nonsense:7667", "udpm://239.255.76.67:7667?ttl=x",
                          "udpm://239.255.76.67:7667?recv_buf_size=-3"}) {
    auto u = lcm::parse_lcm_url(bad);
    EXPECT_FALSE(u.is_ok()) << bad;
    EXPECT_EQ(u.status().code(), StatusCode::kInvalidArgument) << bad;
    EXPECT_NE(u.status().message().find(bad), std::string::npos) << u.status().message();
  }
  auto t = lcm::LcmTransport::open("udpm://10.1.2.3:7667");
  ASSERT_FALSE(t.is_ok());
  EXPECT_NE(t.status().message().find("not a multicast address"), std::string::npos);
}

TEST(LcmDiagnosis, WarnsAboutTheReceiveBuffer) {
  const int64_t rmem_max = lcm::read_rmem_max();
  ASSERT_GT(rmem_max, 0) << "/proc/sys/net/core/rmem_max is not readable";
  auto none = lcm::parse_lcm_url("udpm://239.255.76.67:7667?ttl=0");
  ASSERT_TRUE(none.is_ok());
  auto d = lcm::diagnose_lcm_url(*none);
  ASSERT_EQ(d.warnings.size(), 1u);
  EXPECT_NE(d.warnings[0].find("recv_buf_size=4194304"), std::string::npos) << d.warnings[0];

  auto big = lcm::parse_lcm_url("udpm://239.255.76.67:7667?ttl=0&recv_buf_size=" +
                                  std::to_string(rmem_max * 2));
  ASSERT_TRUE(big.is_ok());
  d = lcm::diagnose_lcm_url(*big);
  ASSERT_EQ(d.warnings.size(), 1u);
  EXPECT_NE(d.warnings[0].find("net.core.rmem_max"), std::string::npos) << d.warnings[0];
  EXPECT_NE(d.warnings[0].find("sysctl"), std::string::npos) << d.warnings[0];

  auto fits = lcm::parse_lcm_url("udpm://239.255.76.67:7667?ttl=0&recv_buf_size=" +
                                   std::to_string(rmem_max));
  ASSERT_TRUE(fits.is_ok());
  EXPECT_TRUE(lcm::diagnose_lcm_url(*fits).warnings.empty());
}

TEST(LcmTransport, FullSizeDepthFrameCrossesLoopback) {
  const std::string url = test_url();
  require_multicast_route(url);
  auto pub = lcm::LcmTransport::open(url);
  ASSERT_TRUE(pub.is_ok()) << pub.status().to_string();
  Listener listener(url);
  ASSERT_TRUE(listener.error().empty()) << listener.error();
  std::mutex m;
  std::vector<int64_t> sequences;
  size_t bad = 0;
  listener.subscribe(lcm::kDepthChannel, [&](const std::string&, const uint8_t* d, size_t n, int64_t) {
    depthfuse::depth_frame_t msg;
    Frame f;
    std::lock_guard<std::mutex> lock(m);
    if (lcm::decode_message(d, n, &msg) != lcm::DecodeResult::kOk ||
        !lcm::decode_depth_frame(msg, &f).is_ok() || f.depth.width != 512) {
      ++bad;
      return;
    }
    sequences.push_back(msg.sequence);
  });
  listener.start();

  Frame f;
  f.intrinsics = CameraIntrinsics::kinect_v2();
  f.depth = DepthImage(512, 424);
  for (size_t i = 0; i < f.depth.depth_m.size(); ++i) f.depth.depth_m[i] = 0.5f + (i % 4000) * 0.001f;
  lcm::DepthEncodeOptions raw;
  raw.compress = false;  // 434 kB: the worst case for UDP fragments
  constexpr int kFrames = 10;
  for (int i = 0; i < kFrames; ++i) {
    f.sequence = static_cast<uint32_t>(i);
    depthfuse::depth_frame_t msg;
    ASSERT_TRUE(lcm::encode_depth_frame(f, raw, &msg).is_ok());
    ASSERT_TRUE((*pub)->publish_message(lcm::kDepthChannel, msg).is_ok());
    std::this_thread::sleep_for(std::chrono::milliseconds(30));
  }
  EXPECT_TRUE(eventually([&] {
    std::lock_guard<std::mutex> lock(m);
    return sequences.size() == kFrames;
  }, std::chrono::seconds(5)));
  std::lock_guard<std::mutex> lock(m);
  EXPECT_EQ(bad, 0u);
  for (size_t i = 0; i < sequences.size(); ++i) EXPECT_EQ(sequences[i], static_cast<int64_t>(i));
}

// A string holding a NUL (decoded from a forged heartbeat, which the monitor copies into its
// status) is sent as LCM means it, up to the NUL: after a flood of such heartbeats the monitor's
// status was never published, because lcm-gen's encoder wrote fewer bytes than it had sized.
TEST(LcmTransport, AStringWithANulIsSentUpToIt) {
  const std::string url = test_url();
  require_multicast_route(url);
  auto pub = lcm::LcmTransport::open(url);
  ASSERT_TRUE(pub.is_ok()) << pub.status().to_string();
  Listener listener(url);
  ASSERT_TRUE(listener.error().empty()) << listener.error();
  std::mutex m;
  std::vector<std::string> names;
  listener.subscribe(lcm::kHeartbeatChannel, [&](const std::string&, const uint8_t* d, size_t n, int64_t) {
    depthfuse::heartbeat_t hb;
    std::lock_guard<std::mutex> lock(m);
    if (lcm::decode_message(d, n, &hb) == lcm::DecodeResult::kOk) names.push_back(hb.name);
  });
  listener.start();
  depthfuse::heartbeat_t hb{};  // lcm-gen leaves its numbers uninitialised
  hb.protocol_version = depthfuse::heartbeat_t::PROTOCOL_VERSION;
  hb.name = std::string("fus\0ion", 7);
  hb.host = "h";
  ASSERT_TRUE((*pub)->publish_message(lcm::kHeartbeatChannel, hb).is_ok());
  EXPECT_TRUE(eventually([&] {
    std::lock_guard<std::mutex> lock(m);
    return !names.empty();
  }, std::chrono::seconds(5)));
  std::lock_guard<std::mutex> lock(m);
  ASSERT_EQ(names.size(), 1u);
  EXPECT_EQ(names[0], "fus");
}

// In a network namespace with only loopback (no multicast route), a daemon must say what is wrong
// and how to fix it. Needs unshare(1) and the right to create namespaces; skipped otherwise.
TEST(LcmTransport, MissingMulticastRouteIsExplained) {
  if (std::system("unshare -n true >/dev/null 2>&1") != 0)
    GTEST_SKIP() << "cannot create a network namespace here (unshare -n)";
  const std::string dir = temp_dir("noroute");
  std::string out;
  const int rc = run_command(
      {"/usr/bin/unshare", "-n", "/bin/sh", "-c",
       "ip link set lo up; exec " + bin("depthfuse-capture") +
           " --key-file '' --source synthetic:corner?frames=2 --lcm '" + test_url() + "'"},
      dir + "/capture.log", &out);
  EXPECT_EQ(rc, 1) << out;
  EXPECT_NE(out.find("no route to the LCM multicast group 239.255.76.67"), std::string::npos) << out;
  EXPECT_NE(out.find("ip route add 224.0.0.0/4 dev lo"), std::string::npos) << out;
  EXPECT_NE(out.find("tools/lcm/route"), std::string::npos) << out;

  // And the fix it suggests works: after tools/lcm/route, the same capture runs.
  const int fixed = run_command(
      {"/usr/bin/unshare", "-n", "/bin/sh", "-c",
       "ip link set lo up && " DEPTHFUSE_TEST_DIR "/../../tools/lcm/route add && exec " +
           bin("depthfuse-capture") +
           " --key-file '' --source synthetic:corner?frames=2 --rate max --lcm '" +
           test_url() + "'"},
      dir + "/capture-fixed.log", &out);
  EXPECT_EQ(fixed, 0) << out;
  EXPECT_NE(out.find("published 2 frames"), std::string::npos) << out;
}

}  // namespace
}  // namespace depthfuse
