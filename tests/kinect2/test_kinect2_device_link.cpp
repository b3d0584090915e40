// The Kinect V2 link state machine, driven by events and a clock of our own: unplug, replug,
// stall, recovery by USB reset, failed opens. No USB and no libfreenect2 involved.
#include <chrono>

#include <gtest/gtest.h>

#include "depthfuse/kinect2/device_link.hpp"

namespace depthfuse::kinect2 {
namespace {

using TimePoint = DeviceLink::TimePoint;

TimePoint at(double seconds) {
  return TimePoint{} + std::chrono::duration_cast<DeviceLink::Clock::duration>(
                           std::chrono::duration<double>(seconds));
}

DeviceLinkConfig config() {
  DeviceLinkConfig c;
  c.stall_timeout_s = 2.0;
  c.first_frame_timeout_s = 10.0;
  c.open_retry_interval_s = 1.0;
  c.open_failures_before_reset = 3;
  return c;
}

// Brings a fresh link to "connected" at time t.
void connect(DeviceLink& link, double t) {
  ASSERT_EQ(link.on_presence(true, at(t)), LinkAction::kOpen);
  ASSERT_EQ(link.on_opened(at(t)), LinkAction::kNone);
  ASSERT_EQ(link.state(), Kinect2State::kConnected);
}

TEST(Kinect2DeviceLink, WaitsWithoutADeviceAndOpensWhenOneAppears) {
  DeviceLink link(config());
  EXPECT_EQ(link.state(), Kinect2State::kWaitingForDevice);
  EXPECT_NE(link.detail().find("no Kinect V2"), std::string::npos) << link.detail();
  EXPECT_EQ(link.on_presence(false, at(0)), LinkAction::kNone);
  EXPECT_EQ(link.on_tick(at(100)), LinkAction::kNone);
  EXPECT_EQ(link.next_deadline(), TimePoint::max()) << "no timer while waiting for hotplug";

  EXPECT_EQ(link.on_presence(true, at(101)), LinkAction::kOpen);
  EXPECT_EQ(link.state(), Kinect2State::kOpening);
  EXPECT_EQ(link.pending(), LinkAction::kOpen);
  // Repeated presence reports and ticks while the open runs ask for nothing more.
  EXPECT_EQ(link.on_presence(true, at(101.1)), LinkAction::kNone);
  EXPECT_EQ(link.on_tick(at(200)), LinkAction::kNone);

  EXPECT_EQ(link.on_opened(at(102)), LinkAction::kNone);
  EXPECT_EQ(link.state(), Kinect2State::kConnected);
  EXPECT_TRUE(link.device_open());
  EXPECT_EQ(link.reconnects(), 0u);
}

TEST(Kinect2DeviceLink, RegularFramesNeverStall) {
  DeviceLink link(config());
  connect(link, 0.0);
  for (int i = 1; i <= 300; ++i) {  // 30 s at 10 Hz
    const double t = 0.1 * i;
    EXPECT_EQ(link.on_frame(at(t)), LinkAction::kNone);
    EXPECT_EQ(link.on_tick(at(t + 0.05)), LinkAction::kNone);
  }
  EXPECT_EQ(link.state(), Kinect2State::kConnected);
  EXPECT_EQ(link.frames(), 300u);
  EXPECT_EQ(link.stalls(), 0u);
  EXPECT_EQ(link.detail(), "streaming");
}

TEST(Kinect2DeviceLink, StallClosesResetsAndReopens) {
  DeviceLink link(config());
  connect(link, 0.0);
  ASSERT_EQ(link.on_frame(at(1.0)), LinkAction::kNone);
  EXPECT_EQ(link.next_deadline(), at(3.0));
  EXPECT_EQ(link.on_tick(at(2.9)), LinkAction::kNone) << "within stall_timeout_s";

  EXPECT_EQ(link.on_tick(at(3.2)), LinkAction::kClose);
  EXPECT_EQ(link.state(), Kinect2State::kStalled);
  EXPECT_EQ(link.stalls(), 1u);
  EXPECT_NE(link.detail().find("no frame for 2.2 s"), std::string::npos) << link.detail();
  EXPECT_EQ(link.on_tick(at(3.3)), LinkAction::kNone) << "the close is pending";

  EXPECT_EQ(link.on_closed(at(3.4)), LinkAction::kResetUsb);
  EXPECT_EQ(link.state(), Kinect2State::kRecovering);
  EXPECT_FALSE(link.device_open());

  EXPECT_EQ(link.on_reset(true, "", at(3.5)), LinkAction::kNone);
  EXPECT_EQ(link.state(), Kinect2State::kOpening);
  EXPECT_EQ(link.usb_resets(), 1u);
  // The reset device needs a moment on the bus before it is reopened.
  EXPECT_EQ(link.next_deadline(), at(4.5));
  EXPECT_EQ(link.on_tick(at(4.0)), LinkAction::kNone);
  EXPECT_EQ(link.on_tick(at(4.6)), LinkAction::kOpen);
  EXPECT_EQ(link.on_opened(at(5.0)), LinkAction::kNone);
  EXPECT_EQ(link.state(), Kinect2State::kConnected);
  EXPECT_EQ(link.reconnects(), 1u);
  EXPECT_EQ(link.on_frame(at(5.5)), LinkAction::kNone);
  EXPECT_EQ(link.frames(), 2u);
}

TEST(Kinect2DeviceLink, FirstFrameGetsItsOwnTimeout) {
  DeviceLink link(config());
  connect(link, 0.0);
  EXPECT_NE(link.detail().find("first frame"), std::string::npos) << link.detail();
  EXPECT_EQ(link.next_deadline(), at(10.0));
  EXPECT_EQ(link.on_tick(at(5.0)), LinkAction::kNone) << "the stall timeout must not apply yet";
  EXPECT_EQ(link.on_tick(at(10.5)), LinkAction::kClose);
  EXPECT_EQ(link.state(), Kinect2State::kStalled);
  EXPECT_NE(link.detail().find("no first frame"), std::string::npos) << link.detail();
}

TEST(Kinect2DeviceLink, UnplugWhileStreamingClosesAndReplugReopens) {
  DeviceLink link(config());
  connect(link, 0.0);
  ASSERT_EQ(link.on_frame(at(0.5)), LinkAction::kNone);

  EXPECT_EQ(link.on_presence(false, at(1.0)), LinkAction::kClose);
  EXPECT_EQ(link.state(), Kinect2State::kWaitingForDevice);
  EXPECT_NE(link.detail().find("unplugged"), std::string::npos) << link.detail();
  EXPECT_EQ(link.on_closed(at(1.1)), LinkAction::kNone) << "unplugged: no USB reset";
  EXPECT_EQ(link.on_tick(at(60.0)), LinkAction::kNone) << "no stall while waiting";
  EXPECT_EQ(link.stalls(), 0u);
  EXPECT_EQ(link.on_frame(at(60.1)), LinkAction::kNone);
  EXPECT_EQ(link.frames(), 1u) << "a straggling frame after unplug is not counted";

  EXPECT_EQ(link.on_presence(true, at(61.0)), LinkAction::kOpen);
  EXPECT_EQ(link.on_opened(at(62.0)), LinkAction::kNone);
  EXPECT_EQ(link.state(), Kinect2State::kConnected);
  EXPECT_EQ(link.reconnects(), 1u);
  EXPECT_EQ(link.usb_resets(), 0u);
}

TEST(Kinect2DeviceLink, UnplugDuringOpenClosesTheFreshHandle) {
  DeviceLink link(config());
  ASSERT_EQ(link.on_presence(true, at(0)), LinkAction::kOpen);
  EXPECT_EQ(link.on_presence(false, at(0.1)), LinkAction::kNone) << "nothing is open yet";
  EXPECT_EQ(link.on_opened(at(0.2)), LinkAction::kClose);
  EXPECT_EQ(link.state(), Kinect2State::kWaitingForDevice);
  EXPECT_EQ(link.on_closed(at(0.3)), LinkAction::kNone);
  EXPECT_FALSE(link.device_open());
}

TEST(Kinect2DeviceLink, UnplugDuringStallRecoveryGoesBackToWaiting) {
  DeviceLink link(config());
  connect(link, 0.0);
  ASSERT_EQ(link.on_tick(at(11.0)), LinkAction::kClose);
  ASSERT_EQ(link.on_closed(at(11.1)), LinkAction::kResetUsb);
  EXPECT_EQ(link.on_presence(false, at(11.2)), LinkAction::kNone);
  EXPECT_EQ(link.on_reset(false, "no USB device", at(11.3)), LinkAction::kNone);
  EXPECT_EQ(link.state(), Kinect2State::kWaitingForDevice);
  EXPECT_EQ(link.on_presence(true, at(12.0)), LinkAction::kOpen);
}

TEST(Kinect2DeviceLink, FailedOpensAreRetriedThenTheDeviceIsReset) {
  DeviceLink link(config());
  ASSERT_EQ(link.on_presence(true, at(0)), LinkAction::kOpen);
  EXPECT_EQ(link.on_open_failed("LIBUSB_ERROR_IO", at(0.5)), LinkAction::kNone);
  EXPECT_EQ(link.state(), Kinect2State::kOpening);
  EXPECT_NE(link.detail().find("LIBUSB_ERROR_IO"), std::string::npos) << link.detail();
  EXPECT_EQ(link.next_deadline(), at(1.5));
  EXPECT_EQ(link.on_tick(at(1.0)), LinkAction::kNone) << "no retry before the interval";
  EXPECT_EQ(link.on_tick(at(1.6)), LinkAction::kOpen);
  EXPECT_EQ(link.on_open_failed("LIBUSB_ERROR_IO", at(1.7)), LinkAction::kNone);
  EXPECT_EQ(link.on_tick(at(2.8)), LinkAction::kOpen);
  EXPECT_EQ(link.on_open_failed("LIBUSB_ERROR_IO", at(2.9)), LinkAction::kResetUsb);
  EXPECT_EQ(link.state(), Kinect2State::kRecovering);
  EXPECT_NE(link.detail().find("3 failed opens"), std::string::npos) << link.detail();

  // A failed reset still leads to a reopen: the device is there.
  EXPECT_EQ(link.on_reset(false, "LIBUSB_ERROR_ACCESS", at(3.0)), LinkAction::kNone);
  EXPECT_EQ(link.state(), Kinect2State::kOpening);
  EXPECT_EQ(link.usb_resets(), 0u) << "only successful resets count";
  EXPECT_NE(link.detail().find("LIBUSB_ERROR_ACCESS"), std::string::npos) << link.detail();
  EXPECT_EQ(link.on_tick(at(4.1)), LinkAction::kOpen);
  EXPECT_EQ(link.on_opened(at(4.5)), LinkAction::kNone);
  EXPECT_EQ(link.state(), Kinect2State::kConnected);
  EXPECT_EQ(link.open_failures(), 0u);
}

TEST(Kinect2DeviceLink, OpenFailureWithoutDeviceWaitsAndKeepsTheReason) {
  DeviceLink link(config());
  ASSERT_EQ(link.on_presence(true, at(0)), LinkAction::kOpen);
  EXPECT_EQ(link.on_presence(false, at(0.1)), LinkAction::kNone);
  EXPECT_EQ(link.on_open_failed("no Kinect V2 with serial 42 is attached", at(0.2)),
            LinkAction::kNone);
  EXPECT_EQ(link.state(), Kinect2State::kWaitingForDevice);
  EXPECT_NE(link.detail().find("serial 42"), std::string::npos) << link.detail();
  EXPECT_EQ(link.on_tick(at(100)), LinkAction::kNone);
}

TEST(Kinect2DeviceLink, StateNamesAreTheHeartbeatWords) {
  EXPECT_STREQ(to_string(Kinect2State::kWaitingForDevice), "waiting for device");
  EXPECT_STREQ(to_string(Kinect2State::kOpening), "opening");
  EXPECT_STREQ(to_string(Kinect2State::kConnected), "connected");
  EXPECT_STREQ(to_string(Kinect2State::kStalled), "stalled");
  EXPECT_STREQ(to_string(Kinect2State::kRecovering), "recovering");
  EXPECT_STREQ(to_string(LinkAction::kResetUsb), "reset USB");
}

}  // namespace
}  // namespace depthfuse::kinect2
