// depthfuse's Kinect V2 depth decoder without libfreenect2: round trip through its forward model,
// the invalid pixels, one thread against two, and bad input. Agreement with libfreenect2's CPU
// decoder is test_kinect2_decoder_agreement.cpp.
#include <gtest/gtest.h>

#include <cmath>
#include <limits>

#include "decoder_scene.hpp"
#include "depthfuse/kinect2/depth_decoder.hpp"
#include "depthfuse/kinect2/packet_encoder.hpp"

namespace depthfuse::kinect2 {
namespace {

using test::scene_images;

struct Decoded {
  DepthImage depth;
  IrImage ir;
};

std::vector<uint8_t> encode_scene(const test::SceneImages& scene) {
  auto encoder = PacketEncoder::create(simulated_p0_tables(), simulated_ir_calibration());
  EXPECT_TRUE(encoder.is_ok()) << encoder.status().to_string();
  std::vector<uint8_t> packet;
  const Status encoded = encoder.value()->encode(scene.depth, scene.ir, &packet);
  EXPECT_TRUE(encoded.is_ok()) << encoded.to_string();
  return packet;
}

Decoded decode(const std::vector<uint8_t>& packet, const DepthDecoderOptions& options) {
  auto decoder = DepthDecoder::create(simulated_p0_tables(), simulated_ir_calibration(), options);
  EXPECT_TRUE(decoder.is_ok()) << decoder.status().to_string();
  Decoded out;
  const Status decoded =
      decoder.value()->decode(RawDepthPacket{1, 0, packet.data(), packet.size()}, &out.depth, &out.ir);
  EXPECT_TRUE(decoded.is_ok()) << decoded.to_string();
  return out;
}

DepthDecoderOptions filters(bool on) {
  DepthDecoderOptions options;
  options.bilateral_filter = on;
  options.edge_aware_filter = on;
  return options;
}

TEST(Kinect2Decoder, RoundTripRecoversDepthWithinPhaseQuantisation) {
  const test::SceneImages scene = scene_images();
  const Decoded out = decode(encode_scene(scene), filters(false));
  ASSERT_EQ(out.depth.width, kRawWidth);
  ASSERT_EQ(out.depth.height, kRawHeight);
  // An 11-bit code holds a correlation to about 1/256 of its value, or to +-0.5 for small ones:
  // the phase error is about 0.3 / amplitude rad, i.e. about 100 mm / amplitude of depth.
  size_t strong = 0, strong_within_2mm = 0, within_bound = 0, compared = 0;
  for (int v = 0; v < kRawHeight; ++v)
    for (int u = 1; u < kRawWidth - 1; ++u) {
      const float ir = scene.ir.amplitude[static_cast<size_t>(v) * kRawWidth + u];
      const float amplitude = ir / 16.0f;
      if (amplitude < 10.0f || ir >= 65535.0f) continue;  // weak or saturated (tested below)
      const double error_mm = std::abs(out.depth.at(u, v) - scene.depth.at(u, v)) * 1000.0;
      ++compared;
      within_bound += error_mm <= 1.0 + 300.0 / amplitude;
      if (amplitude >= 100.0f) {
        ++strong;
        strong_within_2mm += error_mm <= 2.0;
      }
    }
  ASSERT_GT(compared, kRawPixels * 8 / 10);
  ASSERT_GT(strong, kRawPixels / 4);
  EXPECT_EQ(within_bound, compared);
  EXPECT_GE(static_cast<double>(strong_within_2mm) / strong, 0.999);
}

TEST(Kinect2Decoder, RoundTripWithFiltersKeepsSmoothSurfacesAndDropsEdges) {
  const test::SceneImages scene = scene_images();
  const Decoded out = decode(encode_scene(scene), filters(true));
  // The box's front face, away from its edges: as measured.
  size_t close = 0, compared = 0;
  for (int v = 100; v < 280; ++v)
    for (int u = 80; u < 180; ++u) {
      ++compared;
      close += std::abs(out.depth.at(u, v) - scene.depth.at(u, v)) < 0.003f;
    }
  EXPECT_GE(close, compared * 99 / 100);
  // Its left edge, between 1.3 m and the wall at ~3.3 m: no pixel in between survives.
  for (int v = 100; v < 280; ++v)
    for (int u = 55; u < 66; ++u) {
      const float d = out.depth.at(u, v);
      EXPECT_TRUE(d == 0.0f || d < 1.4f || d > 3.2f) << u << "," << v << ": " << d;
    }
}

TEST(Kinect2Decoder, InvalidPixelsAreZero) {
  const test::SceneImages scene = scene_images();
  const Decoded on = decode(encode_scene(scene), filters(true));
  const Decoded off = decode(encode_scene(scene), filters(false));
  for (int v = 0; v < kRawHeight; ++v) {
    // Columns 0 and 511 carry no measurement.
    EXPECT_EQ(off.depth.at(0, v), 0.0f);
    EXPECT_EQ(off.depth.at(kRawWidth - 1, v), 0.0f);
  }
  EXPECT_EQ(off.depth.at(30, 40), 0.0f);  // too weak
  EXPECT_EQ(on.depth.at(30, 40), 0.0f);
  EXPECT_EQ(off.depth.at(495, 215), 0.0f);  // saturated: no depth, full IR
  EXPECT_EQ(off.ir.amplitude[215 * kRawWidth + 495], 65535.0f);
  EXPECT_EQ(on.depth.at(300, 400), 0.0f);  // beyond max_depth with the edge-aware filter on
  EXPECT_NEAR(off.depth.at(300, 400), scene.depth.at(300, 400), 0.01f);  // as libfreenect2
  EXPECT_EQ(on.depth.at(480, 20), 0.0f);  // nearer than min_depth
}

TEST(Kinect2Decoder, TwoThreadsGiveTheSameBytesAsOne) {
  const std::vector<uint8_t> packet = encode_scene(scene_images());
  for (bool on : {false, true}) {
    DepthDecoderOptions two = filters(on);
    two.threads = 2;
    const Decoded a = decode(packet, filters(on));
    const Decoded b = decode(packet, two);
    EXPECT_EQ(a.depth.depth_m, b.depth.depth_m);
    EXPECT_EQ(a.ir.amplitude, b.ir.amplitude);
  }
}

TEST(Kinect2Decoder, P0ResponseRoundTrip) {
  const P0Tables tables = simulated_p0_tables();
  const std::vector<uint8_t> bytes = p0_response(tables);
  ASSERT_EQ(bytes.size(), kP0ResponseBytes);
  auto parsed = parse_p0_response(bytes.data(), bytes.size());
  ASSERT_TRUE(parsed.is_ok()) << parsed.status().to_string();
  EXPECT_EQ(parsed->table, tables.table);
}

TEST(Kinect2Decoder, BadInputGivesClearErrors) {
  const std::vector<uint8_t> packet = encode_scene(scene_images());
  auto created = DepthDecoder::create(simulated_p0_tables(), simulated_ir_calibration(), {});
  ASSERT_TRUE(created.is_ok());
  DepthDecoder& decoder = *created.value();
  DepthImage depth;
  IrImage ir;

  Status s = decoder.decode(RawDepthPacket{1, 0, packet.data(), packet.size() - 704}, &depth, &ir);
  EXPECT_EQ(s.code(), StatusCode::kInvalidArgument);
  EXPECT_NE(s.message().find("2984256 bytes, expected 2984960"), std::string::npos) << s.message();
  s = decoder.decode(RawDepthPacket{1, 0, nullptr, 0}, &depth, &ir);
  EXPECT_NE(s.message().find("no data"), std::string::npos) << s.message();

  ASSERT_TRUE(decoder.decode(RawDepthPacket{7, 0, packet.data(), packet.size()}, &depth, &ir).is_ok());
  const std::vector<float> first = depth.depth_m;
  for (uint32_t wrong : {7u, 6u}) {
    s = decoder.decode(RawDepthPacket{wrong, 0, packet.data(), packet.size()}, &depth, &ir);
    EXPECT_EQ(s.code(), StatusCode::kInvalidArgument);
    EXPECT_NE(s.message().find("does not follow 7"), std::string::npos) << s.message();
  }
  EXPECT_EQ(depth.depth_m, first);  // left as it was
  decoder.restart_sequence();
  EXPECT_TRUE(decoder.decode(RawDepthPacket{1, 0, packet.data(), packet.size()}, &depth, &ir).is_ok());

  IrCalibration nan_calibration = simulated_ir_calibration();
  nan_calibration.k2 = std::numeric_limits<float>::quiet_NaN();
  auto bad = DepthDecoder::create(simulated_p0_tables(), nan_calibration, {});
  EXPECT_EQ(bad.status().code(), StatusCode::kInvalidArgument);
  EXPECT_NE(bad.status().message().find("must be finite"), std::string::npos);

  bad = DepthDecoder::create(P0Tables{}, simulated_ir_calibration(), {});
  EXPECT_EQ(bad.status().code(), StatusCode::kInvalidArgument);
  EXPECT_NE(bad.status().message().find("missing P0 tables"), std::string::npos);
  P0Tables short_tables = simulated_p0_tables();
  short_tables.table[2].resize(100);
  bad = DepthDecoder::create(short_tables, simulated_ir_calibration(), {});
  EXPECT_NE(bad.status().message().find("P0 table 2 has 100 entries"), std::string::npos);
  const std::vector<uint8_t> response = p0_response(simulated_p0_tables());
  EXPECT_EQ(parse_p0_response(response.data(), 1000).status().code(),
            StatusCode::kInvalidArgument);

  DepthDecoderOptions options;
  options.threads = 3;
  EXPECT_NE(DepthDecoder::create(simulated_p0_tables(), simulated_ir_calibration(), options)
                .status().message().find("threads must be 1 or 2"),
            std::string::npos);
  options = {};
  options.max_depth_m = 0.1f;
  EXPECT_EQ(DepthDecoder::create(simulated_p0_tables(), simulated_ir_calibration(), options).status().code(),
            StatusCode::kInvalidArgument);

  auto encoder = PacketEncoder::create(simulated_p0_tables(), simulated_ir_calibration());
  ASSERT_TRUE(encoder.is_ok());
  std::vector<uint8_t> out;
  EXPECT_EQ(encoder.value()->encode(DepthImage(10, 10), IrImage{}, &out).code(),
            StatusCode::kInvalidArgument);
}

}  // namespace
}  // namespace depthfuse::kinect2
