// USB presence: the registry fed by hotplug events (fed by hand here, from another thread as the
// libusb thread does), the real libusb monitor on this machine's bus, and the USB reset helper.
#include <chrono>
#include <thread>

#include <gtest/gtest.h>

#include "depthfuse/kinect2/usb_hotplug.hpp"
#include "depthfuse/kinect2/usb_presence.hpp"
#include "depthfuse/kinect2/usb_reset.hpp"

namespace depthfuse::kinect2 {
namespace {

using Clock = std::chrono::steady_clock;

UsbDeviceRecord device(uint8_t bus, uint8_t address, uint16_t vendor, uint16_t product) {
  UsbDeviceRecord d;
  d.bus = bus;
  d.address = address;
  d.vendor_id = vendor;
  d.product_id = product;
  return d;
}

TEST(Kinect2UsbPresence, OnlyTheStreamingIdsCountAsAKinect) {
  UsbPresence presence;
  EXPECT_FALSE(presence.any_streaming_kinect());
  presence.arrived(device(1, 5, kMicrosoftVendorId, kKinect2ProductIdOther));
  EXPECT_FALSE(presence.any_streaming_kinect()) << "045e:02d9 alone cannot be streamed from";
  presence.arrived(device(1, 6, 0x1d6b, 0x0003));
  EXPECT_FALSE(presence.any_streaming_kinect());
  presence.arrived(device(2, 7, kMicrosoftVendorId, kKinect2ProductId));
  EXPECT_TRUE(presence.any_streaming_kinect());
  EXPECT_EQ(presence.devices().size(), 3u);
  presence.left(device(2, 7, kMicrosoftVendorId, kKinect2ProductId));
  EXPECT_FALSE(presence.any_streaming_kinect());
  presence.arrived(device(3, 1, kMicrosoftVendorId, kKinect2ProductIdPreview));
  EXPECT_TRUE(presence.any_streaming_kinect()) << "the developer preview id 02c4";
}

TEST(Kinect2UsbPresence, EveryEventBumpsTheGeneration) {
  UsbPresence presence;
  const uint64_t g0 = presence.generation();
  presence.arrived(device(1, 2, kMicrosoftVendorId, kKinect2ProductId));
  const uint64_t g1 = presence.generation();
  EXPECT_GT(g1, g0);
  presence.left(device(1, 2, kMicrosoftVendorId, kKinect2ProductId));
  EXPECT_GT(presence.generation(), g1);
}

TEST(Kinect2UsbPresence, ArrivalOnAKnownPortReplacesTheOldDevice) {
  UsbPresence presence;  // a missed departure: the port now holds something else
  presence.arrived(device(1, 2, kMicrosoftVendorId, kKinect2ProductId));
  presence.arrived(device(1, 2, 0x046d, 0xc52b));
  ASSERT_EQ(presence.devices().size(), 1u);
  EXPECT_FALSE(presence.any_streaming_kinect());
}

TEST(Kinect2UsbPresence, PollingSnapshotsBumpOnlyOnChange) {
  UsbPresence presence;
  const std::vector<UsbDeviceRecord> one{device(1, 2, kMicrosoftVendorId, kKinect2ProductId)};
  presence.replace_all(one);
  const uint64_t g = presence.generation();
  presence.replace_all(one);
  EXPECT_EQ(presence.generation(), g) << "same devices, no wake-up";
  presence.replace_all({});
  EXPECT_GT(presence.generation(), g);
  EXPECT_FALSE(presence.any_streaming_kinect());
}

TEST(Kinect2UsbPresence, AWaiterWakesOnAnArrivalFromAnotherThread) {
  UsbPresence presence;
  const uint64_t seen = presence.generation();
  std::thread hotplug([&] {
    std::this_thread::sleep_for(std::chrono::milliseconds(50));
    presence.arrived(device(1, 9, kMicrosoftVendorId, kKinect2ProductId));
  });
  const auto start = Clock::now();
  const uint64_t now_generation =
      presence.wait_for_change(seen, Clock::now() + std::chrono::seconds(60));
  const double waited_s = std::chrono::duration<double>(Clock::now() - start).count();
  hotplug.join();
  EXPECT_NE(now_generation, seen);
  EXPECT_TRUE(presence.any_streaming_kinect());
  EXPECT_LT(waited_s, 30.0) << "woken by the event, not by the deadline";
}

TEST(Kinect2UsbPresence, AWaitWithoutEventsEndsAtItsDeadline) {
  UsbPresence presence;
  const uint64_t seen = presence.generation();
  const auto deadline = Clock::now() + std::chrono::milliseconds(100);
  EXPECT_EQ(presence.wait_for_change(seen, deadline), seen);
  EXPECT_GE(Clock::now(), deadline);
}

TEST(Kinect2UsbPresence, WatchErrorsAreKeptAndWakeWaiters) {
  UsbPresence presence;
  const uint64_t seen = presence.generation();
  presence.set_watch_error("libusb event handling failed: LIBUSB_ERROR_IO");
  EXPECT_NE(presence.generation(), seen);
  EXPECT_EQ(presence.watch_error(), "libusb event handling failed: LIBUSB_ERROR_IO");
  presence.set_watch_error("");
  EXPECT_TRUE(presence.watch_error().empty());
}

TEST(Kinect2UsbIds, TheUdevRuleIds) {
  const auto ids = kinect2_usb_ids();
  ASSERT_EQ(ids.size(), 3u);
  EXPECT_EQ(to_string(ids[0]), "045e:02c4");
  EXPECT_EQ(to_string(ids[1]), "045e:02d8");
  EXPECT_EQ(to_string(ids[2]), "045e:02d9");
  EXPECT_TRUE(is_kinect2_streaming_id(0x045e, 0x02d8));
  EXPECT_TRUE(is_kinect2_streaming_id(0x045e, 0x02c4));
  EXPECT_FALSE(is_kinect2_streaming_id(0x045e, 0x02d9));
  EXPECT_FALSE(is_kinect2_streaming_id(0x045f, 0x02d8));
}

// The real monitor on this machine's USB (no Kinect attached on a build machine).
class Kinect2UsbMonitor : public ::testing::TestWithParam<bool> {};

TEST_P(Kinect2UsbMonitor, StartsReportsNoKinectAndStopsPromptly) {
  UsbHotplugConfig config;
  config.force_polling = GetParam();
  config.poll_interval_s = 0.05;
  config.rescan_interval_s = 0.05;  // exercise the safety-net rescan of the hotplug mode too
  auto monitor = UsbHotplugMonitor::start(config);
  if (!monitor.is_ok()) {
    ASSERT_EQ(monitor.status().code(), StatusCode::kUnavailable) << monitor.status().to_string();
    GTEST_SKIP() << "no USB here: " << monitor.status().message();
  }
  if (config.force_polling) {
    EXPECT_FALSE(monitor.value()->uses_hotplug_events());
  }
  const UsbPresence& presence = monitor.value()->presence();
  if (presence.any_streaming_kinect()) GTEST_SKIP() << "a real Kinect V2 is attached";
  EXPECT_TRUE(presence.watch_error().empty()) << presence.watch_error();
  // Several poll periods pass without a change; the wait still ends at its deadline.
  const uint64_t seen = presence.generation();
  const auto deadline = Clock::now() + std::chrono::milliseconds(300);
  presence.wait_for_change(seen, deadline);
  EXPECT_FALSE(presence.any_streaming_kinect());

  const auto start = Clock::now();
  monitor.value().reset();  // joins the watcher thread
  EXPECT_LT(std::chrono::duration<double>(Clock::now() - start).count(), 10.0);
}

INSTANTIATE_TEST_SUITE_P(HotplugAndPolling, Kinect2UsbMonitor, ::testing::Values(false, true),
                         [](const ::testing::TestParamInfo<bool>& info) {
                           return info.param ? std::string("Polling") : std::string("Hotplug");
                         });

TEST(Kinect2UsbMonitorConfig, RejectsNonsense) {
  UsbHotplugConfig no_ids;
  no_ids.ids.clear();
  EXPECT_EQ(UsbHotplugMonitor::start(no_ids).status().code(), StatusCode::kInvalidArgument);
  UsbHotplugConfig no_interval;
  no_interval.poll_interval_s = 0.0;
  EXPECT_EQ(UsbHotplugMonitor::start(no_interval).status().code(), StatusCode::kInvalidArgument);
  UsbHotplugConfig no_rescan;
  no_rescan.rescan_interval_s = -1.0;
  EXPECT_EQ(UsbHotplugMonitor::start(no_rescan).status().code(), StatusCode::kInvalidArgument);
}

TEST(Kinect2UsbReset, WithoutADeviceItSaysWhatItLookedFor) {
  Result<int> r = reset_usb_devices(kinect2_usb_ids(), "003726334247");
  if (r.is_ok()) GTEST_SKIP() << "a real Kinect V2 with that serial is attached";
  if (r.status().code() == StatusCode::kUnavailable) GTEST_SKIP() << r.status().message();
  EXPECT_EQ(r.status().code(), StatusCode::kNotFound) << r.status().to_string();
  EXPECT_NE(r.status().message().find("045e:02c4/045e:02d8/045e:02d9"), std::string::npos)
      << r.status().message();
  EXPECT_NE(r.status().message().find("003726334247"), std::string::npos) << r.status().message();
}

}  // namespace
}  // namespace depthfuse::kinect2
