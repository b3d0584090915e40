// The source factory (drivers/source_factory.cpp) hands "kinect2[:serial]" to this driver.
#include <gtest/gtest.h>

#include "depthfuse/app_config.hpp"
#include "depthfuse/kinect2/kinect2_source.hpp"
#include "depthfuse/source_factory.hpp"

namespace depthfuse::kinect2 {
namespace {

TEST(Kinect2Factory, KinectSpecsOpenThisDriver) {
  AppConfig config;
  for (const std::string spec : {"kinect2", "kinect2:003726334247"}) {
    auto source = open_frame_source(spec, config);
    if (!source.is_ok() && source.status().code() == StatusCode::kUnavailable)
      GTEST_SKIP() << source.status().message();
    ASSERT_TRUE(source.is_ok()) << spec << ": " << source.status().to_string();
    const Kinect2Source* kinect = as_kinect2_source(*source.value());
    ASSERT_NE(kinect, nullptr) << spec;
    if (spec == "kinect2:003726334247") {
      EXPECT_EQ(kinect->status().serial, "003726334247");
      EXPECT_NE(source.value()->describe().find("003726334247"), std::string::npos);
    }
  }
}

TEST(Kinect2Factory, ConfigErrorsComeThrough) {
  AppConfig config;
  config.capture.kinect2_pipeline = "vulkan";
  auto source = open_frame_source("kinect2", config);
  ASSERT_FALSE(source.is_ok());
  EXPECT_EQ(source.status().code(), StatusCode::kInvalidArgument);
}

}  // namespace
}  // namespace depthfuse::kinect2
