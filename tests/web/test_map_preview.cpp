// The map preview on LCM: map_delta_t's round trip, and the fusion daemon as a real process under a
// fast scan: its deltas stay within map_preview.max_bytes_per_s, and a late joiner's map_request_t
// is answered with a snapshot that holds every chunk sent so far.
#include <gtest/gtest.h>

#include <chrono>
#include <fstream>
#include <mutex>
#include <set>
#include <tuple>
#include <vector>

#include "../lcm/lcm_test_util.hpp"
#include "depthfuse/base/clock.hpp"
#include "depthfuse/lcm/channels.hpp"
#include "depthfuse/lcm/codec.hpp"
#include "depthfuse/map_delta_t.hpp"
#include "depthfuse/map_request_t.hpp"

namespace depthfuse::testing {
namespace {

using std::chrono::seconds;

depthfuse::map_delta_t sample_delta() {
  depthfuse::map_delta_t m{};
  m.protocol_version = depthfuse::map_delta_t::PROTOCOL_VERSION;
  m.utime = 1234;
  m.sender = "fusion";
  m.scan_id = "s1";
  m.sequence = 7;
  m.kind = depthfuse::map_delta_t::KIND_SNAPSHOT;
  m.snapshot_request_id = 42;
  m.snapshot_complete = true;
  m.state = 2;
  m.has_pose = true;
  m.position_m[0] = 1.5;
  m.orientation_wxyz[0] = 1;
  m.chunk_size_m = 0.5f;
  m.position_unit_m = 0.5f / 60000;
  m.uncertainty_unit_m = 1e-5f;
  depthfuse::map_chunk_t c{};
  c.key[0] = -3;
  c.map_points = 10;
  c.coverage = 0.25f;
  c.num_points = 2;
  c.num_coords = 6;
  c.position = {1, -2, 3, 30000, -30000, 0};
  c.normal = {127, 0, 0, 0, -127, 0};
  c.uncertainty = {100, 32767};
  c.num_rgb = 6;
  c.rgb = {255, 0, 0, 0, 255, 0};
  m.chunks.push_back(c);
  m.num_chunks = 1;
  return m;
}

TEST(MapDelta, RoundTripAndTruncation) {
  const auto m = sample_delta();
  const auto bytes = lcm::encode_message(m);
  depthfuse::map_delta_t back;
  ASSERT_EQ(lcm::decode_message(bytes.data(), bytes.size(), &back), lcm::DecodeResult::kOk);
  EXPECT_EQ(back.scan_id, "s1");
  EXPECT_EQ(back.snapshot_request_id, 42);
  EXPECT_TRUE(back.snapshot_complete);
  ASSERT_EQ(back.chunks.size(), 1u);
  EXPECT_EQ(back.chunks[0].key[0], -3);
  EXPECT_EQ(back.chunks[0].position, m.chunks[0].position);
  EXPECT_EQ(back.chunks[0].normal, m.chunks[0].normal);
  EXPECT_EQ(back.chunks[0].uncertainty, m.chunks[0].uncertainty);
  EXPECT_EQ(back.chunks[0].rgb, m.chunks[0].rgb);
  for (size_t cut : {bytes.size() - 1, bytes.size() / 2, size_t{9}})
    EXPECT_EQ(lcm::decode_message(bytes.data(), cut, &back), lcm::DecodeResult::kMalformed) << cut;
  // A chunk claiming 2^30 points in a small message is refused before anything is allocated.
  auto huge = m;
  huge.chunks[0].position.clear();
  huge.chunks[0].normal.clear();
  huge.chunks[0].uncertainty.clear();
  huge.chunks[0].num_rgb = 0;
  huge.chunks[0].rgb.clear();
  huge.chunks[0].num_coords = 0;
  huge.chunks[0].num_points = 0;
  // The chunk's num_points (after key[3], map_points, coverage) patched to 2^30 after encoding.
  auto patched = lcm::encode_message(huge);
  depthfuse::map_delta_t header_only = huge;
  header_only.chunks.clear();
  header_only.num_chunks = 0;
  patched[lcm::encode_message(header_only).size() + 4 * 3 + 4 + 4] = 0x40;
  EXPECT_EQ(lcm::decode_message(patched.data(), patched.size(), &back), lcm::DecodeResult::kMalformed);
}

struct Received {
  double t_s;
  size_t bytes;
  depthfuse::map_delta_t msg;
};

TEST(MapPreviewLive, CapHeldUnderAFastScanAndALateJoinerGetsASnapshot) {
  const std::string url = test_url();
  require_multicast_route(url);
  const std::string dir = temp_dir("map_preview");
  constexpr double kCapBytesPerS = 250000;
  {
    std::ofstream cfg(dir + "/depthfuse.toml");
    cfg << "[map_preview]\nrate_hz = 4.0\nmax_bytes_per_s = " << kCapBytesPerS << "\n";
  }
  Listener listener(url);
  ASSERT_TRUE(listener.error().empty()) << listener.error();
  std::mutex mutex;
  std::vector<Received> received;
  const int64_t t0 = now_utime();
  listener.subscribe(lcm::kMapChannel, [&](const std::string&, const uint8_t* d, size_t n, int64_t) {
    Received r{(now_utime() - t0) * 1e-6, n, {}};
    if (lcm::decode_message(d, n, &r.msg) != lcm::DecodeResult::kOk) return;
    std::lock_guard<std::mutex> lock(mutex);
    received.push_back(std::move(r));
  });
  listener.start();

  Process fusion({bin("depthfuse-fusion"), "--key-file", "", "--lcm", url, "--config", dir + "/depthfuse.toml",
                  "--scan-dir", dir + "/scans", "--autostart", "preview"},
                 dir + "/fusion.log");
  Process capture({bin("depthfuse-capture"), "--key-file", "", "--lcm", url, "--source", "synthetic:room",
                   "--rate", "max", "--loop", "--color", "none"},
                  dir + "/capture.log");
  auto count = [&](auto pred) {
    std::lock_guard<std::mutex> lock(mutex);
    size_t n = 0;
    for (const auto& r : received) n += pred(r);
    return n;
  };
  // The cap must bind: chunks wait for later deltas.
  ASSERT_TRUE(eventually([&] { return count([](const Received& r) { return r.msg.chunks_pending > 0; }) > 3; },
                         seconds(40)))
      << "the cap never held chunks back\n" << fusion.log();
  std::this_thread::sleep_for(seconds(6));

  // The late joiner.
  depthfuse::map_request_t req{};
  req.protocol_version = depthfuse::map_request_t::PROTOCOL_VERSION;
  req.utime = now_utime();
  req.request_id = 4242;
  req.target = "fusion";
  req.sender = "test";
  double asked_s = 0;
  std::set<std::tuple<int, int, int>> sent_before;
  {
    std::lock_guard<std::mutex> lock(mutex);
    asked_s = (now_utime() - t0) * 1e-6;
    for (const auto& r : received)
      for (const auto& c : r.msg.chunks) sent_before.emplace(c.key[0], c.key[1], c.key[2]);
  }
  ASSERT_TRUE(listener.lcm()->publish_message(lcm::kMapRequestChannel, req).is_ok());
  ASSERT_TRUE(eventually([&] {
    return count([](const Received& r) {
             return r.msg.snapshot_request_id == 4242 && r.msg.snapshot_complete;
           }) > 0;
  }, seconds(60))) << "no complete snapshot\n" << fusion.log();
  listener.stop();

  std::set<std::tuple<int, int, int>> in_snapshot;
  double first_s = -1, last_s = 0;
  size_t bytes = 0;
  for (const auto& r : received) {
    if (r.msg.snapshot_request_id == 4242)
      for (const auto& c : r.msg.chunks) in_snapshot.emplace(c.key[0], c.key[1], c.key[2]);
    // The rate over everything after the first second (the bucket starts with one period's worth).
    if (r.t_s < 1.0 || r.msg.scan_id.empty()) continue;
    if (first_s < 0) first_s = r.t_s;
    last_s = r.t_s;
    bytes += r.bytes;
  }
  EXPECT_GT(sent_before.size(), 4u);
  for (const auto& k : sent_before)
    EXPECT_TRUE(in_snapshot.count(k)) << "chunk " << std::get<0>(k) << "," << std::get<1>(k) << ","
                                      << std::get<2>(k) << " sent before the request is not in the snapshot";
  ASSERT_GT(last_s - first_s, 5.0);
  const double rate = bytes / (last_s - first_s);
  // One delta of headroom: the bucket may run one message into debt.
  EXPECT_LE(rate, kCapBytesPerS * 1.15) << "deltas at " << rate << " B/s over a cap of " << kCapBytesPerS;
  EXPECT_GT(rate, kCapBytesPerS * 0.3) << "the preview sent far less than the cap while chunks waited";
  std::printf("map preview under a fast scan: %.0f B/s over %.1f s (cap %.0f); snapshot of %zu chunks "
              "asked at %.1f s\n", rate, last_s - first_s, kCapBytesPerS, in_snapshot.size(), asked_s);
}

}  // namespace
}  // namespace depthfuse::testing
