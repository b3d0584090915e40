// kinect2sim, the simulated Kinect V2, against the scene it renders: in process through the source
// factory, and end to end through a real depthfuse-capture process publishing on real LCM
// (udpm on loopback, a port per test process). Its frames went through the encoder, depthfuse's
// decoder and libfreenect2's registration; their depth must be the scene's within the phase
// quantisation of the packets.
#include <algorithm>
#include <chrono>
#include <cmath>
#include <csignal>
#include <mutex>
#include <string>
#include <vector>

#include <gtest/gtest.h>

#include "depthfuse/app_config.hpp"
#include "depthfuse/daemon/heartbeat.hpp"
#include "depthfuse/depth_frame_t.hpp"
#include "depthfuse/heartbeat_t.hpp"
#include "depthfuse/kinect2/simulated_device.hpp"
#include "depthfuse/lcm/channels.hpp"
#include "depthfuse/lcm/codec.hpp"
#include "depthfuse/lcm/frame_codec.hpp"
#include "depthfuse/source_factory.hpp"
#include "depthfuse/synthetic/scene.hpp"
#include "lcm_test_util.hpp"

namespace depthfuse::kinect2 {
namespace {

constexpr const char* kSpec = "kinect2sim:corner?frames=6&seed=3";

// The depth each pixel of a published frame should have. libfreenect2's registration fills the
// undistorted pixel (u, v) from the distorted pixel nearest to where (u, v) distorts to (its
// Registration: float arithmetic, rounded by + 0.5), and that pixel measured along its own ray.
DepthImage expected_depth(const synthetic::Scene& scene, const Pose& T_world_cam) {
  const IrCalibration c = simulated_ir_calibration();
  DepthImage depth(kRawWidth, kRawHeight);
  for (int v = 0; v < kRawHeight; ++v)
    for (int u = 0; u < kRawWidth; ++u) {
      const float dx = (static_cast<float>(u) - c.cx) / c.fx;
      const float dy = (static_cast<float>(v) - c.cy) / c.fy;
      const float dx2 = dx * dx, dy2 = dy * dy, r2 = dx2 + dy2, dxdy2 = 2 * dx * dy;
      const float kr = 1 + ((c.k3 * r2 + c.k2) * r2 + c.k1) * r2;
      const float mx = c.fx * (dx * kr + c.p2 * (r2 + 2 * dx2) + c.p1 * dxdy2) + c.cx;
      const float my = c.fy * (dy * kr + c.p1 * (r2 + 2 * dy2) + c.p2 * dxdy2) + c.cy;
      const int ix = static_cast<int>(mx + 0.5f), iy = static_cast<int>(my + 0.5f);
      if (ix < 0 || ix >= kRawWidth || iy < 0 || iy >= kRawHeight) continue;
      double xu, yu;
      undistort_normalised(c, (ix - c.cx) / double{c.fx}, (iy - c.cy) / double{c.fy}, &xu, &yu);
      const Eigen::Vector3d dir_w = T_world_cam.rotation() * Eigen::Vector3d(xu, yu, 1.0);
      synthetic::RayHit hit;
      if (scene.raycast(T_world_cam.translation(), dir_w, 20.0, &hit))
        depth.depth_m[static_cast<size_t>(v) * kRawWidth + u] = static_cast<float>(hit.t);
    }
  return depth;
}

struct Agreement {
  size_t expected = 0;   // pixels the sensor should measure (0.6 to 4.4 m, away from the limits)
  size_t measured = 0;   // ... and it did
  size_t within = 0;     // ... within the quantisation
  double worst_m = 0.0;  // largest difference among those measured
};

// The quantisation of a pixel's depth: the 11-bit codes give 1 mm + 300 mm / amplitude (see the
// decoder's round-trip test), the simulated IR amplitude is 36000 / 16 / d^2 (d in m); plus
// `transport_m` for the published units.
Agreement compare(const DepthImage& published, const DepthImage& expected, double transport_m) {
  Agreement a;
  for (size_t i = 0; i < expected.depth_m.size(); ++i) {
    const double truth = expected.depth_m[i];
    if (!(truth > 0.6 && truth < 4.4)) continue;
    ++a.expected;
    const double got = published.depth_m[i];
    if (got <= 0.0) continue;
    ++a.measured;
    const double amplitude = 36000.0 / 16.0 / (truth * truth);
    const double tolerance = 0.001 + 0.3 / amplitude + transport_m;
    const double error = std::abs(got - truth);
    a.within += error <= tolerance;
    a.worst_m = std::max(a.worst_m, error);
  }
  return a;
}

void expect_agreement(const Agreement& a) {
  ASSERT_GT(a.expected, 50000u);
  // The edge-aware filter drops pixels at the walls' edges, as a real Kinect's would.
  EXPECT_GT(a.measured, 0.95 * a.expected) << a.measured << " of " << a.expected;
  // The bilateral filter mixes the two sides of an edge for a pixel or so.
  EXPECT_GT(a.within, 0.99 * a.measured) << a.within << " of " << a.measured << ", worst "
                                          << a.worst_m << " m";
}

TEST(Kinect2Sim, FramesAreTheScenesDepthThroughTheKinectV2Path) {
  auto source = open_frame_source(kSpec, AppConfig{});
  ASSERT_TRUE(source.is_ok()) << source.status().to_string();
  EXPECT_EQ(source.value()->nominal_rate_hz().value_or(0), 30.0);
  EXPECT_EQ(source.value()->frame_count().value_or(0), 6u);
  const synthetic::Scene scene = synthetic::Scene::make(synthetic::SceneKind::kCorner, 3);
  std::vector<Frame> frames;
  for (;;) {
    auto frame = source.value()->next();
    if (!frame.is_ok()) {
      EXPECT_EQ(frame.status().code(), StatusCode::kEndOfStream) << frame.status().to_string();
      break;
    }
    frames.push_back(std::move(frame).value());
  }
  ASSERT_EQ(frames.size(), 6u);
  const IrCalibration c = simulated_ir_calibration();
  for (size_t k = 0; k < frames.size(); k += 5) {
    SCOPED_TRACE("frame " + std::to_string(k));
    const Frame& f = frames[k];
    EXPECT_EQ(f.sensor_serial, "kinect2sim");
    EXPECT_FLOAT_EQ(f.intrinsics.fx, c.fx);
    EXPECT_FLOAT_EQ(f.intrinsics.cy, c.cy);
    ASSERT_TRUE(f.T_world_cam_hint.has_value());
    expect_agreement(compare(f.depth, expected_depth(scene, *f.T_world_cam_hint), 0.0));
  }

  // Rewinding starts the sequence over (the --loop of the capture daemon).
  ASSERT_TRUE(source.value()->rewind().is_ok());
  auto again = source.value()->next();
  ASSERT_TRUE(again.is_ok()) << again.status().to_string();
  EXPECT_TRUE(again->T_world_cam_hint->isApprox(*frames[0].T_world_cam_hint));
  EXPECT_EQ(again->depth.depth_m, frames[0].depth.depth_m);

  const auto status = source.value()->device_status();
  ASSERT_TRUE(status.has_value());
  auto counter = [&](const std::string& key) {
    for (const auto& [name, value] : status->counters)
      if (name == key) return value;
    return -1.0;
  };
  EXPECT_EQ(counter("kinect2sim_frames"), 7);
  EXPECT_EQ(counter("kinect2sim_dropped_packets"), 0);
  EXPECT_GT(counter("kinect2sim_decode_ms_mean"), 0);
}

TEST(Kinect2Sim, CachedPacketsAreReusedWhenTheSequenceLoops) {
  // Room for six packets, of which the sequence has three.
  auto source = open_frame_source("kinect2sim:corner?frames=3&cache_mb=18&seed=3", AppConfig{});
  ASSERT_TRUE(source.is_ok()) << source.status().to_string();
  std::vector<std::vector<float>> first, second;
  for (auto* loop : {&first, &second}) {
    for (auto frame = source.value()->next(); frame.is_ok(); frame = source.value()->next())
      loop->push_back(frame->depth.depth_m);
    ASSERT_TRUE(source.value()->rewind().is_ok());
  }
  ASSERT_EQ(first.size(), 3u);
  EXPECT_EQ(second, first);
  const auto status = source.value()->device_status();
  ASSERT_TRUE(status.has_value());
  const auto& counters = status->counters;
  const auto cached = std::find_if(counters.begin(), counters.end(), [](const auto& kv) {
    return kv.first == "kinect2sim_cached_packets";
  });
  ASSERT_NE(cached, counters.end());
  EXPECT_EQ(cached->second, 3);
}

// first=F, as the synthetic source takes it: the frames from F on, and a rewind back to F.
TEST(Kinect2Sim, StartsAtTheFirstFrameAsked) {
  auto whole = open_frame_source("kinect2sim:corner?frames=4&seed=3", AppConfig{});
  auto tail = open_frame_source("kinect2sim:corner?frames=4&seed=3&first=2", AppConfig{});
  ASSERT_TRUE(whole.is_ok() && tail.is_ok());
  EXPECT_EQ(tail.value()->frame_count().value_or(0), 2u);
  EXPECT_NE(tail.value()->describe().find("from frame 2"), std::string::npos)
      << tail.value()->describe();
  std::vector<Frame> all;
  for (auto f = whole.value()->next(); f.is_ok(); f = whole.value()->next())
    all.push_back(std::move(f).value());
  ASSERT_EQ(all.size(), 4u);
  for (int loop = 0; loop < 2; ++loop) {
    for (size_t k = 2; k < 4; ++k) {
      auto f = tail.value()->next();
      ASSERT_TRUE(f.is_ok()) << f.status().to_string();
      EXPECT_TRUE(f->T_world_cam_hint->isApprox(*all[k].T_world_cam_hint)) << k;
      EXPECT_EQ(f->depth.depth_m, all[k].depth.depth_m) << k;
    }
    EXPECT_EQ(tail.value()->next().status().code(), StatusCode::kEndOfStream);
    ASSERT_TRUE(tail.value()->rewind().is_ok());
  }
}

TEST(Kinect2Sim, BadSpecsAreRefusedNamingTheProblem) {
  for (const char* spec : {"kinect2sim:attic", "kinect2sim:corner?frames=0",
                           "kinect2sim:corner?colour=1", "kinect2sim:corner?cache_mb=-1",
                           "kinect2sim:corner?frames=3&cache_mb=lots",
                           "kinect2sim:corner?frames=3&first=3"}) {
    auto source = open_frame_source(spec, AppConfig{});
    ASSERT_FALSE(source.is_ok()) << spec;
    EXPECT_EQ(source.status().code(), StatusCode::kInvalidArgument) << spec;
    EXPECT_NE(source.status().message().find("kinect2sim"), std::string::npos)
        << source.status().message();
  }
}

TEST(Kinect2SimCapture, TheCaptureDaemonPublishesTheScenesDepthOverLcm) {
  const std::string url = depthfuse::testing::test_url();
  depthfuse::testing::require_multicast_route(url);
  const std::string name = "capture-k2sim";

  depthfuse::testing::Listener listener(url);
  ASSERT_TRUE(listener.error().empty()) << listener.error();
  std::mutex mutex;
  std::vector<Frame> frames;
  std::vector<heartbeat_t> heartbeats;
  listener.subscribe(lcm::kDepthChannel, [&](const std::string&, const uint8_t* data, size_t size,
                                             int64_t) {
    depthfuse::depth_frame_t msg;
    if (lcm::decode_message(data, size, &msg) != lcm::DecodeResult::kOk) return;
    Frame frame;
    if (!lcm::decode_depth_frame(msg, &frame).is_ok()) return;
    std::lock_guard<std::mutex> lock(mutex);
    frames.push_back(std::move(frame));
  });
  listener.subscribe(lcm::kHeartbeatChannel, [&](const std::string&, const uint8_t* data,
                                                   size_t size, int64_t) {
    heartbeat_t hb;
    if (lcm::decode_message(data, size, &hb) != lcm::DecodeResult::kOk || hb.name != name) return;
    std::lock_guard<std::mutex> lock(mutex);
    heartbeats.push_back(hb);
  });
  listener.start();

  const std::string dir = depthfuse::testing::temp_dir("k2sim");
  depthfuse::testing::Process capture({depthfuse::testing::bin("depthfuse-capture"), "--key-file", "", "--source",
                                       kSpec, "--lcm", url, "--name", name, "--linger"},
                                      dir + "/capture.log");
  // Six frames at 30 Hz, then a heartbeat that counts them.
  const bool done = depthfuse::testing::eventually(
      [&] {
        std::lock_guard<std::mutex> lock(mutex);
        return (frames.size() >= 6 && !heartbeats.empty() &&
                daemon::counter_value(heartbeats.back(), "kinect2sim_frames", 0) >= 6) ||
               !capture.running();
      },
      std::chrono::seconds(60));
  ASSERT_TRUE(done) << capture.log();
  capture.signal(SIGTERM);
  ASSERT_TRUE(capture.wait(std::chrono::seconds(15))) << capture.log();
  EXPECT_EQ(capture.exit_code(), 0) << capture.log();

  std::lock_guard<std::mutex> lock(mutex);
  ASSERT_EQ(frames.size(), 6u) << capture.log();
  const heartbeat_t& hb = heartbeats.back();
  EXPECT_EQ(daemon::counter_value(hb, "kinect2sim_dropped_packets", -1), 0);
  EXPECT_EQ(hb.frames_out, 6);
  const synthetic::Scene scene = synthetic::Scene::make(synthetic::SceneKind::kCorner, 3);
  for (size_t k : {size_t{0}, size_t{5}}) {
    SCOPED_TRACE("frame " + std::to_string(k));
    const Frame& f = frames[k];
    EXPECT_EQ(f.sequence, k);
    EXPECT_EQ(f.sensor_serial, "kinect2sim");
    ASSERT_TRUE(f.T_world_cam_hint.has_value());
    // Published in whole millimetres.
    expect_agreement(compare(f.depth, expected_depth(scene, *f.T_world_cam_hint), 0.0005));
  }
}

}  // namespace
}  // namespace depthfuse::kinect2
