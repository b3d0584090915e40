// depthfuse's depth decoder against libfreenect2's CPU decoder on the same packets (encoded from
// a synthetic scene), with the filters on and off: depth within 1 mm on 99.9 % of the pixels both
// measure, the same invalid pixels to within 0.1 %, the same IR.
#include <gtest/gtest.h>

#include <cmath>
#include <cstdio>

#include "decoder_scene.hpp"
#include "depthfuse/kinect2/depth_decoder.hpp"
#include "depthfuse/kinect2/packet_encoder.hpp"
#include "freenect2_reference.hpp"

namespace depthfuse::kinect2 {
namespace {

// As the driver reads libfreenect2's depth (conversion.hpp): 0, negative, NaN, inf = none.
bool measured(float depth) { return std::isfinite(depth) && depth > 0.0f; }

struct Filters {
  bool bilateral;
  bool edge_aware;
};

class DecoderAgreement : public ::testing::TestWithParam<Filters> {};

TEST_P(DecoderAgreement, SameDepthAndInvalidPixelsAsLibfreenect2) {
  const Filters filters = GetParam();
  const P0Tables p0 = simulated_p0_tables();
  const IrCalibration calibration = simulated_ir_calibration();
  DepthDecoderOptions options;
  options.bilateral_filter = filters.bilateral;
  options.edge_aware_filter = filters.edge_aware;
  auto ours = DepthDecoder::create(p0, calibration, options);
  ASSERT_TRUE(ours.is_ok()) << ours.status().to_string();
  test::Freenect2CpuDecoder theirs(p0, calibration, options.min_depth_m, options.max_depth_m,
                                   filters.bilateral, filters.edge_aware);
  auto encoder = PacketEncoder::create(p0, calibration);
  ASSERT_TRUE(encoder.is_ok());

  size_t both = 0, within_1mm = 0, validity_differs = 0, ir_close = 0, pixels = 0;
  double worst_mm = 0.0;
  std::vector<uint8_t> packet;
  DepthImage depth;
  IrImage ir;
  std::vector<float> their_depth_mm, their_ir;
  for (int frame = 0; frame < 3; ++frame) {
    const test::SceneImages scene = test::scene_images(frame);
    ASSERT_TRUE(encoder.value()->encode(scene.depth, scene.ir, &packet).is_ok());
    const uint32_t sequence = static_cast<uint32_t>(frame + 1);
    ASSERT_TRUE(ours.value()->decode(RawDepthPacket{sequence, 0, packet.data(), packet.size()},
                                     &depth, &ir).is_ok());
    theirs.decode(&packet, sequence, &their_depth_mm, &their_ir);
    ASSERT_EQ(their_depth_mm.size(), kRawPixels);
    for (size_t i = 0; i < kRawPixels; ++i) {
      ++pixels;
      const bool ours_valid = depth.depth_m[i] > 0.0f;
      const bool theirs_valid = measured(their_depth_mm[i]);
      validity_differs += ours_valid != theirs_valid;
      ir_close += std::abs(ir.amplitude[i] - their_ir[i]) <= 1e-3f * std::max(1.0f, their_ir[i]);
      if (ours_valid && theirs_valid) {
        const double difference_mm = std::abs(depth.depth_m[i] * 1000.0 - their_depth_mm[i]);
        ++both;
        within_1mm += difference_mm <= 1.0;
        worst_mm = std::max(worst_mm, difference_mm);
      }
    }
  }
  const double agree = static_cast<double>(within_1mm) / both;
  const double invalid_differs = static_cast<double>(validity_differs) / pixels;
  std::printf("filters bilateral=%d edge=%d: %zu pixels measured by both, %.5f %% within 1 mm "
              "(worst %.3f mm); validity differs on %.5f %% of pixels\n",
              filters.bilateral, filters.edge_aware, both, 100.0 * agree, worst_mm,
              100.0 * invalid_differs);
  EXPECT_GT(both, pixels / 2);
  EXPECT_GE(agree, 0.999);
  EXPECT_LE(invalid_differs, 0.001);
  EXPECT_EQ(ir_close, pixels);
}

// Not bilateral off with edge-aware on: libfreenect2 then reads its uninitialised edge-test
// buffer (cpu_depth_packet_processor.cpp), so its output is not defined; ours passes the test.
INSTANTIATE_TEST_SUITE_P(Filters, DecoderAgreement,
                         ::testing::Values(Filters{true, true}, Filters{false, false},
                                           Filters{true, false}),
                         [](const ::testing::TestParamInfo<Filters>& info) {
                           return std::string(info.param.bilateral ? "Bilateral" : "NoBilateral") +
                                  (info.param.edge_aware ? "EdgeAware" : "NoEdgeAware");
                         });

}  // namespace
}  // namespace depthfuse::kinect2
