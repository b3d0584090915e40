// The Kinect V2 source on a machine without a Kinect: it opens, says plainly that it waits for the
// device, never blocks longer than it is allowed to, and rejects bad configuration with the key's
// name. Real libusb and libfreenect2 underneath; no mocks.
#include <atomic>
#include <chrono>
#include <thread>

#include <gtest/gtest.h>

#include "depthfuse/app_config.hpp"
#include "depthfuse/kinect2/kinect2_source.hpp"
#include "depthfuse/kinect2/packet_pipeline.hpp"

namespace depthfuse::kinect2 {
namespace {

using Clock = std::chrono::steady_clock;

double seconds_since(Clock::time_point start) {
  return std::chrono::duration<double>(Clock::now() - start).count();
}

Kinect2Options quick_options(const std::string& serial = "") {
  Kinect2Options options;
  options.serial = serial;
  options.max_wait_s = 0.3;
  return options;
}

// Opens the source, or skips the test where the premise (no Kinect, USB present) does not hold.
std::unique_ptr<Kinect2Source> open_or_skip(const Kinect2Options& options) {
  auto source = open_kinect2(options);
  if (!source.is_ok() && source.status().code() == StatusCode::kUnavailable) return nullptr;
  EXPECT_TRUE(source.is_ok()) << source.status().to_string();
  if (!source.is_ok()) return nullptr;
  return std::move(source).value();
}

TEST(Kinect2Source, WithoutADeviceNextIsUnavailableWithAClearMessage) {
  auto source = open_or_skip(quick_options());
  if (!source) GTEST_SKIP() << "USB is not accessible on this machine";

  const auto start = Clock::now();
  Result<Frame> frame = source->next();
  const double waited_s = seconds_since(start);
  if (frame.is_ok() || source->status().state != Kinect2State::kWaitingForDevice)
    GTEST_SKIP() << "a Kinect V2 is attached: " << source->status().summary();
  ASSERT_FALSE(frame.is_ok());
  EXPECT_EQ(frame.status().code(), StatusCode::kUnavailable) << frame.status().to_string();
  EXPECT_NE(frame.status().message().find("no Kinect V2"), std::string::npos)
      << frame.status().message();
  EXPECT_NE(frame.status().message().find("waiting for one to be plugged in"), std::string::npos)
      << frame.status().message();
  // Bounded: max_wait_s (0.3 s), with a wide margin for a loaded machine. A hang fails here (or at
  // the CTest timeout), not silently.
  EXPECT_GE(waited_s, 0.25) << "it should wait for the device, not return at once";
  EXPECT_LT(waited_s, 20.0);

  const Kinect2Status status = source->status();
  EXPECT_EQ(status.state, Kinect2State::kWaitingForDevice);
  EXPECT_EQ(status.frames, 0u);
  EXPECT_EQ(status.pipeline, "depthfuse");
  EXPECT_NE(status.summary().find("waiting for device"), std::string::npos) << status.summary();
  EXPECT_NE(source->describe().find("waiting for device"), std::string::npos)
      << source->describe();
  EXPECT_NE(source->describe().find("kinect2:"), std::string::npos) << source->describe();
}

TEST(Kinect2Source, TheRequestedSerialIsInTheMessageAndStatus) {
  auto source = open_or_skip(quick_options("003726334247"));
  if (!source) GTEST_SKIP() << "USB is not accessible on this machine";
  Result<Frame> frame = source->next();
  ASSERT_FALSE(frame.is_ok());
  EXPECT_EQ(frame.status().code(), StatusCode::kUnavailable);
  EXPECT_NE(frame.status().message().find("with serial 003726334247"), std::string::npos)
      << frame.status().message();
  EXPECT_EQ(source->status().serial, "003726334247");
  EXPECT_NE(source->describe().find("003726334247"), std::string::npos);
}

TEST(Kinect2Source, EveryCallIsBoundedAndTheSourceKeepsWaiting) {
  auto source = open_or_skip(quick_options());
  if (!source) GTEST_SKIP() << "USB is not accessible on this machine";
  for (int i = 0; i < 3; ++i) {
    const auto start = Clock::now();
    Result<Frame> frame = source->next();
    if (frame.is_ok()) GTEST_SKIP() << "a Kinect V2 is attached";
    EXPECT_EQ(frame.status().code(), StatusCode::kUnavailable);
    EXPECT_LT(seconds_since(start), 20.0);
  }
  EXPECT_EQ(source->status().state, Kinect2State::kWaitingForDevice);
  EXPECT_EQ(source->rewind().code(), StatusCode::kUnsupported);
  EXPECT_FALSE(source->frame_count().has_value());
}

TEST(Kinect2Source, StatusCanBeReadWhileNextWaits) {
  auto source = open_or_skip(quick_options());
  if (!source) GTEST_SKIP() << "USB is not accessible on this machine";
  std::atomic<bool> done{false};
  std::thread capture([&] {
    for (int i = 0; i < 3; ++i) (void)source->next();
    done = true;
  });
  int reads = 0;
  while (!done) {  // a heartbeat thread, much faster than a real one
    const Kinect2Status status = source->status();
    EXPECT_FALSE(status.summary().empty());
    EXPECT_FALSE(source->describe().empty());
    ++reads;
    std::this_thread::sleep_for(std::chrono::milliseconds(5));
  }
  capture.join();
  EXPECT_GT(reads, 0);
}

TEST(Kinect2Source, OpensFromTheAppConfigAndIsRecognisable) {
  AppConfig config;
  auto source = open_kinect2_source("", config);
  if (!source.is_ok() && source.status().code() == StatusCode::kUnavailable)
    GTEST_SKIP() << source.status().message();
  ASSERT_TRUE(source.is_ok()) << source.status().to_string();
  const Kinect2Source* kinect = as_kinect2_source(*source.value());
  ASSERT_NE(kinect, nullptr);
  EXPECT_EQ(kinect->status().pipeline, "depthfuse");
  ASSERT_TRUE(source.value()->nominal_rate_hz().has_value());
  EXPECT_DOUBLE_EQ(*source.value()->nominal_rate_hz(), 30.0);
}

TEST(Kinect2Options, ComeFromTheConfigFile) {
  const std::string toml = R"(
[capture]
source = "kinect2:003726334247"
kinect2_pipeline = "cpu"
kinect2_min_depth_m = 0.7
kinect2_max_depth_m = 3.5
kinect2_bilateral_filter = false
kinect2_edge_aware_filter = true
kinect2_stall_timeout_s = 1.5

[[device]]
serial = "003726334247"
fx = 366.1
fy = 366.3
cx = 258.2
cy = 204.9
)";
  Result<AppConfig> config = parse_app_config(toml, "kinect2 test");
  ASSERT_TRUE(config.is_ok()) << config.status().to_string();
  Result<Kinect2Options> options = kinect2_options_from_config("003726334247", config.value());
  ASSERT_TRUE(options.is_ok()) << options.status().to_string();
  EXPECT_EQ(options->serial, "003726334247");
  EXPECT_EQ(options->pipeline, "cpu");
  EXPECT_DOUBLE_EQ(options->min_depth_m, 0.7);
  EXPECT_DOUBLE_EQ(options->max_depth_m, 3.5);
  EXPECT_FALSE(options->bilateral_filter);
  EXPECT_TRUE(options->edge_aware_filter);
  EXPECT_DOUBLE_EQ(options->stall_timeout_s, 1.5);
  EXPECT_GE(options->first_frame_timeout_s, options->stall_timeout_s);
  ASSERT_EQ(options->calibrations.size(), 1u);
  EXPECT_DOUBLE_EQ(options->calibrations[0].intrinsics.fx, 366.1);
}

TEST(Kinect2Options, BadValuesNameTheirKey) {
  AppConfig config;
  config.capture.kinect2_pipeline = "vulkan";
  Result<Kinect2Options> r = kinect2_options_from_config("", config);
  ASSERT_FALSE(r.is_ok());
  EXPECT_EQ(r.status().code(), StatusCode::kInvalidArgument);
  EXPECT_NE(r.status().message().find("capture.kinect2_pipeline"), std::string::npos);

  config = AppConfig();
  config.capture.kinect2_min_depth_m = 3.0;
  config.capture.kinect2_max_depth_m = 2.0;
  r = kinect2_options_from_config("", config);
  ASSERT_FALSE(r.is_ok());
  EXPECT_NE(r.status().message().find("capture.kinect2_max_depth_m"), std::string::npos)
      << r.status().message();

  config = AppConfig();
  config.capture.kinect2_stall_timeout_s = 0.0;
  r = kinect2_options_from_config("", config);
  ASSERT_FALSE(r.is_ok());
  EXPECT_NE(r.status().message().find("capture.kinect2_stall_timeout_s"), std::string::npos);

  config = AppConfig();
  DeviceCalibration vga;
  vga.serial = "123";
  vga.intrinsics.width = 640;
  vga.intrinsics.height = 480;
  config.devices.push_back(vga);
  r = kinect2_options_from_config("", config);
  ASSERT_FALSE(r.is_ok());
  EXPECT_NE(r.status().message().find("'123'"), std::string::npos) << r.status().message();

  // open_kinect2 validates hand-made options the same way.
  Kinect2Options bad = quick_options();
  bad.max_wait_s = -1.0;
  EXPECT_EQ(open_kinect2(bad).status().code(), StatusCode::kInvalidArgument);
}

TEST(Kinect2Options, APipelineNotInLibfreenect2IsUnsupported) {
  const auto compiled = kinect2::compiled_pipelines();
  for (const std::string name : {"opengl", "opencl", "cuda"}) {
    if (std::find(compiled.begin(), compiled.end(), name) != compiled.end()) continue;
    AppConfig config;
    config.capture.kinect2_pipeline = name;
    auto source = open_kinect2_source("", config);
    ASSERT_FALSE(source.is_ok()) << name;
    EXPECT_EQ(source.status().code(), StatusCode::kUnsupported) << name;
    EXPECT_NE(source.status().message().find("not compiled into libfreenect2"), std::string::npos)
        << source.status().message();
  }
}

}  // namespace
}  // namespace depthfuse::kinect2
