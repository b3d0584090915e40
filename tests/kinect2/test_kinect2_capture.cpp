// The capture daemon with a Kinect V2 source: its heartbeat carries the device state, and with no
// Kinect attached depthfuse-capture --source kinect2 waits for one (without spinning) instead of
// exiting. The daemon runs as a real process on real LCM (udpm on loopback, a port per test
// process); where a Kinect is attached the waiting test skips itself.
#include <unistd.h>

#include <chrono>
#include <csignal>
#include <cstdio>
#include <fstream>
#include <mutex>
#include <optional>
#include <sstream>
#include <string>
#include <vector>

#include <gtest/gtest.h>

#include "depthfuse/daemon/heartbeat.hpp"
#include "depthfuse/heartbeat_t.hpp"
#include "depthfuse/kinect2/kinect2_source.hpp"
#include "depthfuse/lcm/channels.hpp"
#include "depthfuse/lcm/codec.hpp"
#include "lcm_test_util.hpp"

namespace depthfuse::kinect2 {
namespace {

using depthfuse::testing::Listener;
using depthfuse::testing::Process;
namespace dd = depthfuse::daemon;

Kinect2Status status_in(Kinect2State state) {
  Kinect2Status status;
  status.state = state;
  status.detail = "why: " + std::string(to_string(state));
  status.frames = 1200;
  status.stalls = 2;
  status.usb_resets = 1;
  status.reconnects = 3;
  status.usb_hotplug = true;
  return status;
}

heartbeat_t heartbeat_in(int8_t state) {
  heartbeat_t hb = dd::HeartbeatBase("capture").make(state);
  hb.last_error = "earlier error";
  return hb;
}

TEST(Kinect2CaptureHeartbeat, DeviceStateSetsTheStateOfAReadingDaemon) {
  struct Case {
    Kinect2State kinect;
    int8_t expected;
    const char* key;
  };
  const Case cases[] = {
      {Kinect2State::kWaitingForDevice, heartbeat_t::STATE_IDLE, "kinect2_state_waiting_for_device"},
      {Kinect2State::kOpening, heartbeat_t::STATE_IDLE, "kinect2_state_opening"},
      {Kinect2State::kConnected, heartbeat_t::STATE_RUNNING, "kinect2_state_connected"},
      {Kinect2State::kStalled, heartbeat_t::STATE_ERROR, "kinect2_state_stalled"},
      {Kinect2State::kRecovering, heartbeat_t::STATE_ERROR, "kinect2_state_recovering"},
  };
  for (const Case& c : cases) {
    SCOPED_TRACE(to_string(c.kinect));
    for (const int8_t reading : {heartbeat_t::STATE_RUNNING, heartbeat_t::STATE_IDLE}) {
      heartbeat_t hb = heartbeat_in(reading);
      const Kinect2Status status = status_in(c.kinect);
      dd::add_device_status(to_device_status(status), &hb);
      EXPECT_EQ(hb.state, c.expected);
      EXPECT_EQ(dd::counter_value(hb, "kinect2_state", -1), static_cast<int>(c.kinect));
      EXPECT_EQ(dd::counter_value(hb, c.key, 0), 1.0);
      EXPECT_EQ(dd::counter_value(hb, "kinect2_frames", -1), 1200);
      EXPECT_EQ(dd::counter_value(hb, "kinect2_stalls", -1), 2);
      EXPECT_EQ(dd::counter_value(hb, "kinect2_usb_resets", -1), 1);
      EXPECT_EQ(dd::counter_value(hb, "kinect2_reconnects", -1), 3);
      EXPECT_EQ(dd::counter_value(hb, "kinect2_usb_hotplug", -1), 1);
      int state_keys = 0;
      for (const auto& kv : hb.counters) state_keys += kv.key.rfind("kinect2_state_", 0) == 0;
      EXPECT_EQ(state_keys, 1);
      EXPECT_EQ(hb.num_counters, static_cast<int32_t>(hb.counters.size()));
      if (c.kinect == Kinect2State::kConnected) {
        EXPECT_EQ(hb.last_error, "earlier error");  // the daemon's own errors stay visible
      } else {
        EXPECT_EQ(hb.last_error, status.summary());
        EXPECT_EQ(hb.last_error.rfind(to_string(c.kinect), 0), 0u) << hb.last_error;
      }
    }
  }
}

TEST(Kinect2CaptureHeartbeat, PausedStoppingAndStuckDaemonsKeepTheirState) {
  for (const int8_t state : {heartbeat_t::STATE_PAUSED, heartbeat_t::STATE_STOPPING,
                             heartbeat_t::STATE_ERROR, heartbeat_t::STATE_STARTING}) {
    heartbeat_t hb = heartbeat_in(state);
    dd::add_device_status(to_device_status(status_in(Kinect2State::kWaitingForDevice)), &hb);
    EXPECT_EQ(hb.state, state);
    EXPECT_EQ(hb.last_error, "earlier error");
    EXPECT_EQ(dd::counter_value(hb, "kinect2_state", -1), 0);  // the device state is still there
  }
}

// CPU seconds (user + system) the process `pid` has used so far, from /proc/<pid>/stat.
std::optional<double> cpu_seconds(pid_t pid) {
  std::ifstream in("/proc/" + std::to_string(pid) + "/stat");
  std::string line;
  if (!std::getline(in, line)) return std::nullopt;
  // The command name (field 2) is in parentheses and may hold spaces: count from after it.
  const auto close = line.rfind(')');
  if (close == std::string::npos) return std::nullopt;
  std::istringstream fields(line.substr(close + 2));
  std::string field;
  unsigned long long utime = 0, stime = 0;
  for (int i = 3; i <= 15 && fields >> field; ++i) {
    if (i == 14) utime = std::stoull(field);
    if (i == 15) stime = std::stoull(field);
  }
  return static_cast<double>(utime + stime) / static_cast<double>(::sysconf(_SC_CLK_TCK));
}

TEST(Kinect2Capture, WithNoKinectTheDaemonWaitsAndItsHeartbeatSaysSo) {
  const std::string url = depthfuse::testing::test_url();
  depthfuse::testing::require_multicast_route(url);
  const std::string name = "capture-k2wait";

  Listener listener(url);
  ASSERT_TRUE(listener.error().empty()) << listener.error();
  std::mutex mutex;
  std::vector<heartbeat_t> heard;
  listener.subscribe(lcm::kHeartbeatChannel, [&](const std::string&, const uint8_t* data,
                                                   size_t size, int64_t) {
    heartbeat_t hb;
    if (lcm::decode_message(data, size, &hb) != lcm::DecodeResult::kOk || hb.name != name)
      return;
    std::lock_guard<std::mutex> lock(mutex);
    heard.push_back(hb);
  });
  listener.start();
  auto heartbeats = [&] {
    std::lock_guard<std::mutex> lock(mutex);
    return heard;
  };

  const std::string dir = depthfuse::testing::temp_dir("k2wait");
  const auto started = std::chrono::steady_clock::now();
  Process capture({depthfuse::testing::bin("depthfuse-capture"), "--key-file", "", "--source", "kinect2", "--lcm", url,
                   "--name", name},
                  dir + "/capture.log");

  // Heartbeats over at least 3 s (one a second from the start): the daemon is still there.
  const bool heard_enough = depthfuse::testing::eventually(
      [&] { return heartbeats().size() >= 4 || !capture.running(); }, std::chrono::seconds(20));
  ASSERT_TRUE(heard_enough) << capture.log();
  ASSERT_TRUE(capture.running()) << "depthfuse-capture exited (" << capture.exit_code()
                                 << ") instead of waiting for the Kinect:\n" << capture.log();
  const double wall_s =
      std::chrono::duration<double>(std::chrono::steady_clock::now() - started).count();
  const std::optional<double> cpu_s = cpu_seconds(capture.pid());

  const heartbeat_t last = heartbeats().back();
  if (dd::counter_value(last, "kinect2_state", -1) == static_cast<int>(Kinect2State::kConnected))
    GTEST_SKIP() << "this test needs no Kinect V2 attached (it checks that the daemon waits for "
                    "one), and the daemon reports one connected; unplug it to run the test";

  EXPECT_EQ(last.state, heartbeat_t::STATE_IDLE) << dd::state_name(last.state);
  EXPECT_EQ(dd::counter_value(last, "kinect2_state", -1),
            static_cast<int>(Kinect2State::kWaitingForDevice));
  EXPECT_EQ(dd::counter_value(last, "kinect2_state_waiting_for_device", 0), 1.0);
  EXPECT_EQ(dd::counter_value(last, "kinect2_frames", -1), 0);
  EXPECT_EQ(dd::counter_value(last, "source_errors", -1), 0);  // waiting is not an error
  EXPECT_EQ(last.last_error.rfind("waiting for device: ", 0), 0u) << last.last_error;
  EXPECT_EQ(last.frames_out, 0);

  // Waiting sleeps: a busy loop would use about as much CPU time as wall time.
  ASSERT_TRUE(cpu_s.has_value());
  EXPECT_LT(*cpu_s, 0.5 * wall_s) << "CPU " << *cpu_s << " s in " << wall_s << " s of waiting";

  // It still stops cleanly when asked, saying so in a last heartbeat.
  capture.signal(SIGTERM);
  ASSERT_TRUE(capture.wait(std::chrono::seconds(15))) << capture.log();
  EXPECT_EQ(capture.exit_code(), 0) << capture.log();
  EXPECT_TRUE(depthfuse::testing::eventually(
      [&] { return heartbeats().back().state == heartbeat_t::STATE_STOPPING; },
      std::chrono::seconds(2)));
}

}  // namespace
}  // namespace depthfuse::kinect2
