// The synthetic driver as a FrameSource, and its spec strings.
#include <gtest/gtest.h>

#include <string>

#include "depthfuse/synthetic/synthetic_source.hpp"

namespace depthfuse::synthetic {
namespace {

TEST(SyntheticSpec, ParsesKeys) {
  auto c = parse_synthetic_spec(
      "rooms?frames=36000&seed=7&pose_noise_m=0.02&pose_noise_deg=1.5&rate_hz=15&noise=0");
  ASSERT_TRUE(c.is_ok()) << c.status().to_string();
  EXPECT_EQ(c->scene, SceneKind::kRooms);
  EXPECT_EQ(c->frames, 36000);
  EXPECT_EQ(c->seed, 7u);
  EXPECT_EQ(c->pose_noise_m, 0.02);
  EXPECT_EQ(c->pose_noise_deg, 1.5);
  EXPECT_EQ(c->rate_hz, 15.0);
  EXPECT_FALSE(c->noise.enabled);
  auto plain = parse_synthetic_spec("corner");
  ASSERT_TRUE(plain.is_ok());
  EXPECT_EQ(plain->frames, 60);
  EXPECT_TRUE(plain->noise.enabled);
  EXPECT_TRUE(parse_synthetic_spec("room?").is_ok());
}

TEST(SyntheticSpec, ErrorsNameTheKeyOrValue) {
  struct Case {
    const char* spec;
    const char* needle;
  };
  for (const Case& k :
       {Case{"", "unknown synthetic scene ''"}, Case{"kitchen", "kitchen"},
        Case{"corner?frames=abc", "'abc' for 'frames'"}, Case{"corner?frames=0", "'frames'"},
        Case{"corner?frames=12x", "'12x'"}, Case{"corner?seed=-1", "'seed'"},
        Case{"corner?pose_noise_m=x", "'pose_noise_m'"},
        Case{"corner?pose_noise_deg=-2", "'pose_noise_deg'"},
        Case{"corner?pose_noise_m=nan", "'pose_noise_m'"}, Case{"corner?rate_hz=0", "'rate_hz'"},
        Case{"corner?noise=maybe", "'noise'"}, Case{"corner?bogus=1", "unknown key 'bogus'"},
        Case{"corner?frames", "'frames' has no value"}, Case{"corner?first=-1", "'first'"},
        Case{"corner?frames=5&first=5",
             "first (the first frame streamed) must be in [0, frames - 1] = [0, 4]"}}) {
    auto c = parse_synthetic_spec(k.spec);
    ASSERT_FALSE(c.is_ok()) << "accepted '" << k.spec << "'";
    EXPECT_EQ(c.status().code(), StatusCode::kInvalidArgument);
    EXPECT_NE(c.status().message().find(k.needle), std::string::npos)
        << "'" << c.status().message() << "' lacks '" << k.needle << "'";
    auto opened = open_synthetic_source(k.spec, AppConfig());
    ASSERT_FALSE(opened.is_ok());
    EXPECT_EQ(opened.status().code(), StatusCode::kInvalidArgument);
  }
}

TEST(SyntheticSource, StreamsRewindsAndCarriesPoseHints) {
  auto opened = open_synthetic_source("room?frames=3&seed=5&pose_noise_m=0.01&pose_noise_deg=0.5",
                                      AppConfig());
  ASSERT_TRUE(opened.is_ok()) << opened.status().to_string();
  FrameSource& src = *opened.value();
  EXPECT_NE(src.describe().find("synthetic:room"), std::string::npos) << src.describe();
  EXPECT_NE(src.describe().find("3 frames"), std::string::npos);
  ASSERT_TRUE(src.nominal_rate_hz().has_value());
  EXPECT_EQ(*src.nominal_rate_hz(), 30.0);
  ASSERT_TRUE(src.frame_count().has_value());
  EXPECT_EQ(*src.frame_count(), 3u);

  auto* synth = dynamic_cast<SyntheticSource*>(&src);
  ASSERT_NE(synth, nullptr);
  Frame first;
  for (uint32_t i = 0; i < 3; ++i) {
    auto f = src.next();
    ASSERT_TRUE(f.is_ok()) << f.status().to_string();
    EXPECT_EQ(f->sequence, i);
    ASSERT_TRUE(f->T_world_cam_hint.has_value());
    EXPECT_TRUE(f->T_world_cam_hint->isApprox(synth->sequence().T_world_cam_perturbed(i), 0.0));
    EXPECT_FALSE(f->T_world_cam_hint->isApprox(synth->sequence().T_world_cam_true(i), 1e-6));
    if (i == 0) first = std::move(f).value();
  }
  auto end = src.next();
  ASSERT_FALSE(end.is_ok());
  EXPECT_EQ(end.status().code(), StatusCode::kEndOfStream);
  ASSERT_TRUE(src.rewind().is_ok());
  auto again = src.next();
  ASSERT_TRUE(again.is_ok());
  EXPECT_EQ(again->sequence, 0u);
  EXPECT_EQ(again->depth.depth_m, first.depth.depth_m);
}

// A stretch of a long walk on its own: the walk's own sequence numbers, stamps and poses.
TEST(SyntheticSource, StartsAtTheFirstFrameAsked) {
  auto opened = open_synthetic_source("furnished?frames=36000&first=35998&hints=0", AppConfig());
  ASSERT_TRUE(opened.is_ok()) << opened.status().to_string();
  FrameSource& src = *opened.value();
  auto* synth = dynamic_cast<SyntheticSource*>(&src);
  ASSERT_NE(synth, nullptr);
  EXPECT_NE(src.describe().find("from frame 35998"), std::string::npos) << src.describe();
  ASSERT_TRUE(src.frame_count().has_value());
  EXPECT_EQ(*src.frame_count(), 2u);
  for (uint32_t i = 35998; i < 36000; ++i) {
    auto f = src.next();
    ASSERT_TRUE(f.is_ok()) << f.status().to_string();
    EXPECT_EQ(f->sequence, i);
    EXPECT_EQ(f->utime, synth->sequence().utime(i));
    EXPECT_FALSE(f->T_world_cam_hint.has_value());
  }
  EXPECT_EQ(src.next().status().code(), StatusCode::kEndOfStream);
  ASSERT_TRUE(src.rewind().is_ok());
  auto again = src.next();
  ASSERT_TRUE(again.is_ok());
  EXPECT_EQ(again->sequence, 35998u);
}

TEST(SyntheticSource, TakesIntrinsicsFromTheSyntheticCalibration) {
  AppConfig config;
  DeviceCalibration cal;
  cal.serial = "synthetic";
  cal.intrinsics.width = 320;
  cal.intrinsics.height = 240;
  cal.intrinsics.fx = cal.intrinsics.fy = 250.0;
  cal.intrinsics.cx = 159.5;
  cal.intrinsics.cy = 119.5;
  config.devices.push_back(cal);
  auto opened = open_synthetic_source("corner?frames=1&noise=off", config);
  ASSERT_TRUE(opened.is_ok()) << opened.status().to_string();
  auto f = opened.value()->next();
  ASSERT_TRUE(f.is_ok());
  EXPECT_EQ(f->intrinsics.fx, 250.0);
  EXPECT_EQ(f->depth.width, 320);
  EXPECT_EQ(f->depth.height, 240);
  EXPECT_NE(opened.value()->describe().find("no sensor noise"), std::string::npos);
}

}  // namespace
}  // namespace depthfuse::synthetic
