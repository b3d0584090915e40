// The "depthfuse" pipeline's step in the driver: a raw packet as libfreenect2's DumpPacketPipeline
// delivers it (a Frame::Raw) through depthfuse's decoder to the float-millimetre depth frame the
// rest of the driver (registration, conversion) takes. Packets from the encoder; no device.
#include <gtest/gtest.h>

#include <cstring>

#include "decoder_scene.hpp"
#include "depthfuse/kinect2/frame_assembly.hpp"
#include "depthfuse/kinect2/packet_decoding.hpp"
#include "depthfuse/kinect2/packet_encoder.hpp"

namespace depthfuse::kinect2 {
namespace {

libfreenect2::Freenect2Device::IrCameraParams scene_ir_params() {
  return ir_camera_params(simulated_ir_calibration());
}

struct RawFrame {
  std::vector<uint8_t> packet;
  libfreenect2::Frame frame;
  explicit RawFrame(std::vector<uint8_t> bytes, uint32_t sequence)
      : packet(std::move(bytes)), frame(1, 1, packet.size(), packet.data()) {
    frame.format = libfreenect2::Frame::Raw;
    frame.sequence = sequence;
  }
};

std::vector<uint8_t> scene_packet() {
  const test::SceneImages scene = test::scene_images();
  auto encoder = PacketEncoder::create(simulated_p0_tables(), simulated_ir_calibration());
  std::vector<uint8_t> packet;
  EXPECT_TRUE(encoder.value()->encode(scene.depth, scene.ir, &packet).is_ok());
  return packet;
}

TEST(Kinect2PacketDecoding, RawPacketBecomesTheDecodersDepthInMillimetres) {
  const std::vector<uint8_t> response = p0_response(simulated_p0_tables());
  auto decoding = PacketDecoding::create(response.data(), response.size(), scene_ir_params(), {});
  ASSERT_TRUE(decoding.is_ok()) << decoding.status().to_string();
  RawFrame raw(scene_packet(), 5);
  libfreenect2::Frame depth_mm(512, 424, 4);
  ASSERT_TRUE(decoding.value()->decode(raw.frame, &depth_mm).is_ok());
  EXPECT_EQ(depth_mm.format, libfreenect2::Frame::Float);
  EXPECT_EQ(depth_mm.sequence, 5u);

  auto decoder = DepthDecoder::create(simulated_p0_tables(), simulated_ir_calibration(), {});
  DepthImage depth;
  IrImage ir;
  ASSERT_TRUE(decoder.value()
                  ->decode(RawDepthPacket{5, 0, raw.packet.data(), raw.packet.size()}, &depth, &ir)
                  .is_ok());
  size_t measured = 0;
  for (size_t i = 0; i < kRawPixels; ++i) {
    float mm;
    std::memcpy(&mm, depth_mm.data + 4 * i, 4);
    EXPECT_FLOAT_EQ(mm, depth.depth_m[i] * 1000.0f);
    measured += mm > 0.0f;
  }
  EXPECT_GT(measured, kRawPixels / 2);
}

TEST(Kinect2PacketDecoding, BadPacketsAreRefusedWithTheirReason) {
  const std::vector<uint8_t> response = p0_response(simulated_p0_tables());
  auto decoding = PacketDecoding::create(response.data(), response.size(), scene_ir_params(), {});
  ASSERT_TRUE(decoding.is_ok());
  libfreenect2::Frame depth_mm(512, 424, 4);

  std::vector<uint8_t> short_packet = scene_packet();
  short_packet.resize(1000);
  RawFrame short_frame(short_packet, 1);
  Status s = decoding.value()->decode(short_frame.frame, &depth_mm);
  EXPECT_EQ(s.code(), StatusCode::kInvalidArgument);
  EXPECT_NE(s.message().find("1000 bytes"), std::string::npos) << s.message();

  RawFrame good(scene_packet(), 9);
  ASSERT_TRUE(decoding.value()->decode(good.frame, &depth_mm).is_ok());
  s = decoding.value()->decode(good.frame, &depth_mm);  // the same sequence again
  EXPECT_NE(s.message().find("does not follow 9"), std::string::npos) << s.message();

  libfreenect2::Frame not_raw(512, 424, 4);
  not_raw.format = libfreenect2::Frame::Float;
  EXPECT_NE(decoding.value()->decode(not_raw, &depth_mm).message().find("raw depth packet"),
            std::string::npos);

  // No P0 tables from the device, or NaN calibration: the pipeline cannot start.
  auto missing = PacketDecoding::create(nullptr, 0, scene_ir_params(), {});
  EXPECT_NE(missing.status().message().find("missing P0 tables"), std::string::npos)
      << missing.status().message();
  libfreenect2::Freenect2Device::IrCameraParams nan_ir = scene_ir_params();
  nan_ir.fx = std::nanf("");
  auto bad_ir = PacketDecoding::create(response.data(), response.size(), nan_ir, {});
  EXPECT_NE(bad_ir.status().message().find("must be finite"), std::string::npos);
}

// The driver's path for a frame set (FrameAssembly, shared by the Kinect V2 source and kinect2sim):
// each bad packet is refused with its reason and counted, and the next good one is a frame.
TEST(Kinect2FrameAssembly, BadPacketsAreCountedDropsAndTheNextGoodOneIsAFrame) {
  const std::vector<uint8_t> response = p0_response(simulated_p0_tables());
  auto decoding = PacketDecoding::create(response.data(), response.size(), scene_ir_params(), {});
  ASSERT_TRUE(decoding.is_ok()) << decoding.status().to_string();
  auto assembly = FrameAssembly::create(scene_ir_params(), {}, "test",
                                        std::move(decoding).value());
  ASSERT_TRUE(assembly.is_ok()) << assembly.status().to_string();
  FrameAssembly& a = *assembly.value();

  RawFrame first(scene_packet(), 7);
  auto frame = a.assemble(first.frame, nullptr);
  ASSERT_TRUE(frame.is_ok()) << frame.status().to_string();
  EXPECT_EQ(frame->sequence, 7u);
  EXPECT_EQ(frame->sensor_serial, "test");
  EXPECT_EQ(frame->depth.width, 512);
  size_t measured = 0;
  for (float d : frame->depth.depth_m) measured += d > 0.0f;
  EXPECT_GT(measured, kRawPixels / 2);

  std::vector<uint8_t> short_packet = scene_packet();
  short_packet.resize(2984256);
  RawFrame truncated(short_packet, 8);
  RawFrame repeated(scene_packet(), 7);
  const std::pair<const RawFrame*, const char*> bad[] = {
      {&truncated, "2984256 bytes, expected 2984960"}, {&repeated, "does not follow 7"}};
  for (const auto& [raw, reason] : bad) {
    auto refused = a.assemble(raw->frame, nullptr);
    ASSERT_FALSE(refused.is_ok());
    EXPECT_EQ(refused.status().code(), StatusCode::kInvalidArgument);
    EXPECT_NE(refused.status().message().find(reason), std::string::npos)
        << refused.status().message();
  }
  EXPECT_EQ(a.stats().dropped, 2u);

  RawFrame next(scene_packet(), 9);
  frame = a.assemble(next.frame, nullptr);
  ASSERT_TRUE(frame.is_ok()) << frame.status().to_string();
  EXPECT_EQ(frame->sequence, 9u);
  EXPECT_EQ(a.stats().frames, 2u);
  EXPECT_EQ(a.stats().dropped, 2u);
}

}  // namespace
}  // namespace depthfuse::kinect2
