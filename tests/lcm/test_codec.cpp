// Frame <-> message conversion is lossless, and no byte sequence makes a decoder crash: truncated,
// corrupt, foreign and wrong-version payloads are each recognised.
#include <gtest/gtest.h>

#include <chrono>
#include <cstring>
#include <functional>
#include <random>

#include "depthfuse/color_frame_t.hpp"
#include "depthfuse/command_t.hpp"
#include "depthfuse/daemon/process_info.hpp"
#include "depthfuse/depth_frame_t.hpp"
#include "depthfuse/heartbeat_t.hpp"
#include "depthfuse/lcm/channels.hpp"
#include "depthfuse/lcm/codec.hpp"
#include "depthfuse/lcm/frame_codec.hpp"
#include "depthfuse/pose2_t.hpp"
#include "depthfuse/pose_t.hpp"
#include "depthfuse/status_t.hpp"

namespace depthfuse {
namespace {

using lcm::DecodeResult;

// Depth quantised to whole millimetres the way a Kinect V2 delivers it, with holes, plus colour.
Frame make_frame(int w, int h, uint32_t seed, bool with_color = true) {
  Frame f;
  f.utime = 1'700'000'000'000'000 + seed;
  f.sequence = seed;
  f.sensor_serial = "012345678912";
  f.intrinsics.width = w;
  f.intrinsics.height = h;
  f.intrinsics.fx = 365.1;
  f.intrinsics.fy = 364.9;
  f.intrinsics.cx = w / 2.0 - 0.5;
  f.intrinsics.cy = h / 2.0 - 0.5;
  f.depth = DepthImage(w, h);
  std::mt19937 rng(seed);
  std::uniform_int_distribution<int> mm(500, 4500);
  for (int v = 0; v < h; ++v)
    for (int u = 0; u < w; ++u) {
      const bool hole = (u * 7 + v * 13 + static_cast<int>(seed)) % 17 == 0;
      f.depth.at(u, v) = hole ? 0.0f : static_cast<float>(mm(rng) * 0.001);
    }
  if (with_color) {
    f.color.width = w;
    f.color.height = h;
    f.color.rgb.resize(static_cast<size_t>(w) * h * 3);
    for (size_t i = 0; i < f.color.rgb.size(); ++i) f.color.rgb[i] = static_cast<uint8_t>((i * 31 + seed) & 0xff);
  }
  Pose hint = Pose::Identity();
  hint.linear() = Eigen::AngleAxisd(0.3, Eigen::Vector3d(1, 2, 3).normalized()).toRotationMatrix();
  hint.translation() = Eigen::Vector3d(1.5, -0.25, 0.75);
  f.T_world_cam_hint = hint;
  return f;
}

TEST(DepthFrameCodec, RoundTripIsLosslessRawAndZstd) {
  const Frame f = make_frame(512, 424, 7);
  for (const int mode : {0, 1, 2}) {
    const bool compress = mode > 0;
    lcm::DepthEncodeOptions opt;
    opt.compress = compress;
    opt.predict_rows = mode == 2;
    depthfuse::depth_frame_t msg;
    ASSERT_TRUE(lcm::encode_depth_frame(f, opt, &msg).is_ok());
    EXPECT_EQ(msg.protocol_version, lcm::kProtocolVersion);
    // Through the wire format, not just the struct.
    const auto bytes = lcm::encode_message(msg);
    depthfuse::depth_frame_t back_msg;
    ASSERT_EQ(lcm::decode_message(bytes.data(), bytes.size(), &back_msg), DecodeResult::kOk);
    Frame back;
    ASSERT_TRUE(lcm::decode_depth_frame(back_msg, &back).is_ok());
    EXPECT_EQ(back.utime, f.utime);
    EXPECT_EQ(back.sequence, f.sequence);
    EXPECT_EQ(back.sensor_serial, f.sensor_serial);
    EXPECT_EQ(back.intrinsics.width, 512);
    EXPECT_DOUBLE_EQ(back.intrinsics.fx, f.intrinsics.fx);
    EXPECT_DOUBLE_EQ(back.intrinsics.cy, f.intrinsics.cy);
    ASSERT_EQ(back.depth.depth_m.size(), f.depth.depth_m.size());
    size_t differ = 0;
    for (size_t i = 0; i < f.depth.depth_m.size(); ++i) differ += back.depth.depth_m[i] != f.depth.depth_m[i];
    EXPECT_EQ(differ, 0u) << "mode " << mode;
    EXPECT_EQ(msg.encoding, mode == 0   ? depthfuse::depth_frame_t::ENCODING_RAW_UINT16
                            : mode == 1 ? depthfuse::depth_frame_t::ENCODING_ZSTD_UINT16
                                        : depthfuse::depth_frame_t::ENCODING_ZSTD_DELTA_UINT16);
    ASSERT_TRUE(back.T_world_cam_hint.has_value());
    EXPECT_TRUE(back.T_world_cam_hint->isApprox(*f.T_world_cam_hint, 1e-12));
    // Encoding the decoded frame again gives the same bytes: nothing drifts on re-publishing.
    depthfuse::depth_frame_t again;
    ASSERT_TRUE(lcm::encode_depth_frame(back, opt, &again).is_ok());
    EXPECT_EQ(again.data, msg.data);
    if (compress) {
      EXPECT_LT(msg.data.size(), 512u * 424u * 2u);
    }
  }
}

TEST(DepthFrameCodec, RowPredictorHandlesExtremesAndSmoothDepthShrinks) {
  // Jumps between 0 and 65535 counts wrap around in the predictor: still exact.
  Frame f = make_frame(16, 4, 1, false);
  const float extremes[] = {0.0f, 65.535f, 0.001f, 65.534f, 0.0f, 32.768f, 32.767f, 0.0f};
  for (size_t i = 0; i < f.depth.depth_m.size(); ++i) f.depth.depth_m[i] = extremes[i % 8];
  depthfuse::depth_frame_t msg;
  ASSERT_TRUE(lcm::encode_depth_frame(f, {}, &msg).is_ok());
  Frame back;
  ASSERT_TRUE(lcm::decode_depth_frame(msg, &back).is_ok());
  for (size_t i = 0; i < f.depth.depth_m.size(); ++i)
    EXPECT_NEAR(back.depth.depth_m[i], f.depth.depth_m[i], 1e-6) << i;
  // A slanted wall with millimetre noise: the predictor beats plain zstd.
  Frame wall = make_frame(512, 424, 2, false);
  std::mt19937 rng(3);
  std::normal_distribution<double> noise(0.0, 1.5);
  for (int v = 0; v < 424; ++v)
    for (int u = 0; u < 512; ++u)
      wall.depth.at(u, v) = static_cast<float>(std::lround(1500 + 2.0 * u + v + noise(rng)) * 0.001);
  depthfuse::depth_frame_t plain, predicted;
  lcm::DepthEncodeOptions no_pred;
  no_pred.predict_rows = false;
  ASSERT_TRUE(lcm::encode_depth_frame(wall, no_pred, &plain).is_ok());
  ASSERT_TRUE(lcm::encode_depth_frame(wall, {}, &predicted).is_ok());
  EXPECT_LT(predicted.data.size(), plain.data.size() * 3 / 4)
      << predicted.data.size() << " vs " << plain.data.size();
  ASSERT_TRUE(lcm::decode_depth_frame(predicted, &back).is_ok());
  EXPECT_EQ(back.depth.depth_m, wall.depth.depth_m);
}

TEST(DepthFrameCodec, ContinuousDepthIsQuantisedToHalfAUnit) {
  Frame f = make_frame(64, 48, 3, false);
  std::mt19937 rng(5);
  std::uniform_real_distribution<float> d(0.3f, 6.0f);
  for (auto& v : f.depth.depth_m) v = d(rng);
  f.depth.depth_m[0] = -1.0f;                      // invalid -> 0
  f.depth.depth_m[1] = std::nanf("");              // invalid -> 0
  f.depth.depth_m[2] = 70.0f;                      // beyond 65535 mm -> 0
  depthfuse::depth_frame_t msg;
  ASSERT_TRUE(lcm::encode_depth_frame(f, {}, &msg).is_ok());
  Frame back;
  ASSERT_TRUE(lcm::decode_depth_frame(msg, &back).is_ok());
  EXPECT_EQ(back.depth.depth_m[0], 0.0f);
  EXPECT_EQ(back.depth.depth_m[1], 0.0f);
  EXPECT_EQ(back.depth.depth_m[2], 0.0f);
  for (size_t i = 3; i < f.depth.depth_m.size(); ++i)
    ASSERT_NEAR(back.depth.depth_m[i], f.depth.depth_m[i], 0.0005 + 1e-6) << i;
}

TEST(DepthFrameCodec, FinerUnitKeepsTumPrecision) {
  // TUM PNGs count 1/5000 m: with depth_unit_m = 0.0002 those values survive exactly.
  Frame f = make_frame(32, 24, 9, false);
  for (size_t i = 0; i < f.depth.depth_m.size(); ++i)
    f.depth.depth_m[i] = static_cast<float>((2500 + 3 * i) * 0.0002);
  lcm::DepthEncodeOptions opt;
  opt.depth_unit_m = 0.0002;
  depthfuse::depth_frame_t msg;
  ASSERT_TRUE(lcm::encode_depth_frame(f, opt, &msg).is_ok());
  Frame back;
  ASSERT_TRUE(lcm::decode_depth_frame(msg, &back).is_ok());
  EXPECT_EQ(back.depth.depth_m, f.depth.depth_m);
}

// A frame beyond what the receiver takes is refused on its header, before any decompression: a
// few bytes that claim a huge image, or intrinsics no camera has.
TEST(DepthFrameCodec, RefusesFramesBeyondTheLimitsBeforeDecoding) {
  depthfuse::depth_frame_t vga;
  ASSERT_TRUE(lcm::encode_depth_frame(make_frame(640, 480, 3, false), {}, &vga).is_ok());
  Frame out;
  ASSERT_TRUE(lcm::decode_depth_frame(vga, &out).is_ok()) << "640x480 is within the defaults";
  lcm::FrameLimits kinect_v2;
  kinect_v2.max_width = 512;
  kinect_v2.max_height = 424;
  Status st = lcm::decode_depth_frame(vga, &out, kinect_v2);
  EXPECT_EQ(st.code(), StatusCode::kCorrupt);
  EXPECT_NE(st.message().find("640x480 is larger than the sensors"), std::string::npos) << st.message();

  const Frame small = make_frame(64, 48, 4, false);
  depthfuse::depth_frame_t good;
  ASSERT_TRUE(lcm::encode_depth_frame(small, {}, &good).is_ok());
  auto expect_refused = [&](depthfuse::depth_frame_t m, const std::string& names) {
    const Status refused = lcm::decode_depth_frame(m, &out);
    EXPECT_EQ(refused.code(), StatusCode::kCorrupt) << names;
    EXPECT_NE(refused.message().find(names), std::string::npos) << refused.message();
  };
  auto m = good;
  m.intrinsics.width = m.intrinsics.height = 4096;  // the data would inflate to 32 MiB
  expect_refused(m, "4096x4096 is larger");
  m = good;
  m.intrinsics.fx = 1e-30;
  expect_refused(m, "focal lengths");
  m = good;
  m.intrinsics.fy = 1e30;
  expect_refused(m, "focal lengths");
  m = good;
  m.intrinsics.cx = -5;
  expect_refused(m, "principal point");
  m = good;
  m.depth_unit_m = 1e-300;
  expect_refused(m, "depth_unit_m");

  depthfuse::color_frame_t color;
  color.width = color.height = 30000;  // a 30000x30000 JPEG would decode into 2.7 GB
  color.encoding = depthfuse::color_frame_t::ENCODING_JPEG;
  ColorImage image;
  st = lcm::decode_color_frame(color, &image);
  EXPECT_EQ(st.code(), StatusCode::kCorrupt);
  EXPECT_NE(st.message().find("30000x30000 is larger"), std::string::npos) << st.message();
}

// A JPEG whose own header claims a huge image is refused before OpenCV allocates for it (the
// fuzzer found 685 bytes that made imdecode ask for 2.3 GB).
TEST(ColorFrameCodec, JpegDeclaringAHugeImageIsRefusedBeforeDecoding) {
  depthfuse::color_frame_t msg;
  lcm::ColorEncodeOptions jpeg;
  jpeg.encoding = lcm::ColorEncoding::kJpeg;
  ASSERT_TRUE(lcm::encode_color_frame(make_frame(32, 24, 5), jpeg, &msg).is_ok());
  ColorImage back;
  ASSERT_TRUE(lcm::decode_color_frame(msg, &back).is_ok());
  size_t sof = 0;
  for (size_t i = 2; i + 9 < msg.data.size() && !sof; ++i)
    if (msg.data[i] == 0xFF && msg.data[i + 1] == 0xC0) sof = i;
  ASSERT_GT(sof, 0u) << "no baseline frame header in the encoded JPEG";
  for (size_t k : {sof + 5, sof + 7}) {  // height, width: 30000
    msg.data[k] = 30000 >> 8;
    msg.data[k + 1] = 30000 & 0xff;
  }
  const Status st = lcm::decode_color_frame(msg, &back);
  EXPECT_EQ(st.code(), StatusCode::kCorrupt);
  EXPECT_NE(st.message().find("the JPEG is 30000x30000"), std::string::npos) << st.message();
}

TEST(DepthFrameCodec, RejectsInconsistentMessages) {
  const Frame f = make_frame(64, 48, 1, false);
  depthfuse::depth_frame_t good;
  ASSERT_TRUE(lcm::encode_depth_frame(f, {}, &good).is_ok());
  Frame out;
  auto expect_corrupt = [&](depthfuse::depth_frame_t m, const char* what) {
    const Status st = lcm::decode_depth_frame(m, &out);
    EXPECT_EQ(st.code(), StatusCode::kCorrupt) << what << ": " << st.to_string();
  };
  auto m = good;
  m.intrinsics.width = 0;
  expect_corrupt(m, "zero width");
  m = good;
  m.intrinsics.height = 100000;
  expect_corrupt(m, "huge height");
  m = good;
  m.intrinsics.fx = -1;
  expect_corrupt(m, "negative fx");
  m = good;
  m.depth_unit_m = 0;
  expect_corrupt(m, "zero unit");
  m = good;
  m.encoding = 9;
  expect_corrupt(m, "unknown encoding");
  m = good;
  m.data.resize(m.data.size() / 2);
  m.data_size = static_cast<int32_t>(m.data.size());
  expect_corrupt(m, "truncated zstd");
  m = good;
  m.intrinsics.width = 32;  // inflates to the wrong size
  expect_corrupt(m, "size mismatch");
  m = good;
  for (auto& b : m.data) b ^= 0x5a;
  expect_corrupt(m, "scrambled zstd");
  m = good;
  m.encoding = depthfuse::depth_frame_t::ENCODING_RAW_UINT16;
  expect_corrupt(m, "raw with wrong length");
}

// Issue 36: a frame with a 999 m hint was fused there, and the map's extent became 1 km. A hint
// outside the workspace, or one that is no pose, is left out and said; the frame is kept (its
// depth is good) as one without a hint, which tracking places.
TEST(DepthFrameCodec, APoseHintOutsideTheWorkspaceIsLeftOutAndTheFrameKept) {
  depthfuse::depth_frame_t good;
  ASSERT_TRUE(lcm::encode_depth_frame(make_frame(64, 48, 4, false), {}, &good).is_ok());
  good.has_pose_hint = true;
  lcm::FrameLimits site;
  site.max_pose_hint_m = 100.0;
  auto decode = [&](const depthfuse::depth_frame_t& m, lcm::DepthFrameNotes* notes) {
    Frame out;
    out.T_world_cam_hint = Pose::Identity();  // whatever was there before goes
    const Status st = lcm::decode_depth_frame(m, &out, site, nullptr, notes);
    EXPECT_TRUE(st.is_ok()) << st.to_string();
    EXPECT_EQ(out.depth.width, 64);
    return out;
  };
  lcm::DepthFrameNotes notes;
  auto m = good;
  m.hint_position_m[0] = 99.0;  // inside: kept
  Frame kept = decode(m, &notes);
  ASSERT_TRUE(kept.T_world_cam_hint.has_value());
  EXPECT_DOUBLE_EQ(kept.T_world_cam_hint->translation().x(), 99.0);
  EXPECT_TRUE(notes.pose_hint_refused.empty()) << notes.pose_hint_refused;

  struct Case {
    std::string what;
    std::function<void(depthfuse::depth_frame_t*)> spoil;
    std::string says;
  };
  const std::vector<Case> cases = {
      {"999 m", [](auto* f) { f->hint_position_m[1] = 999.0; },
       "pose hint 999.0 m from the origin, beyond the workspace (100 m"},
      {"1e30 m", [](auto* f) { f->hint_position_m[2] = -1e30; }, "beyond the workspace"},
      {"NaN", [](auto* f) { f->hint_position_m[0] = std::nan(""); }, "non-finite"},
      {"zero quaternion", [](auto* f) { for (double& q : f->hint_orientation_wxyz) q = 0; },
       "zero quaternion"},
  };
  for (const Case& c : cases) {
    m = good;
    c.spoil(&m);
    const Frame left = decode(m, &notes);
    EXPECT_FALSE(left.T_world_cam_hint.has_value()) << c.what;
    EXPECT_NE(notes.pose_hint_refused.find("depth frame " + std::to_string(m.sequence)),
              std::string::npos)
        << notes.pose_hint_refused;
    EXPECT_NE(notes.pose_hint_refused.find(c.says), std::string::npos) << notes.pose_hint_refused;
    EXPECT_NE(notes.pose_hint_refused.find("the frame is taken without it"), std::string::npos);
  }
  // Without notes the same frame is decoded alike.
  m = good;
  m.hint_position_m[1] = 999.0;
  EXPECT_FALSE(decode(m, nullptr).T_world_cam_hint.has_value());
}

TEST(ColorFrameCodec, RawAndZstdAreExactJpegIsClose) {
  const Frame f = make_frame(64, 48, 2);
  for (auto enc : {lcm::ColorEncoding::kRaw, lcm::ColorEncoding::kZstd, lcm::ColorEncoding::kJpeg}) {
    lcm::ColorEncodeOptions opt;
    opt.encoding = enc;
    depthfuse::color_frame_t msg;
    ASSERT_TRUE(lcm::encode_color_frame(f, opt, &msg).is_ok());
    const auto bytes = lcm::encode_message(msg);
    depthfuse::color_frame_t back_msg;
    ASSERT_EQ(lcm::decode_message(bytes.data(), bytes.size(), &back_msg), DecodeResult::kOk);
    ColorImage back;
    ASSERT_TRUE(lcm::decode_color_frame(back_msg, &back).is_ok());
    ASSERT_EQ(back.width, 64);
    ASSERT_EQ(back.height, 48);
    ASSERT_EQ(back.rgb.size(), f.color.rgb.size());
    if (enc != lcm::ColorEncoding::kJpeg) {
      EXPECT_EQ(back.rgb, f.color.rgb);
    }
  }
  // A smooth image survives JPEG within a few levels.
  Frame smooth = f;
  for (int v = 0; v < 48; ++v)
    for (int u = 0; u < 64; ++u)
      for (int c = 0; c < 3; ++c) smooth.color.rgb[(v * 64 + u) * 3 + c] = static_cast<uint8_t>(u * 2 + v + c * 40);
  lcm::ColorEncodeOptions opt;
  opt.encoding = lcm::ColorEncoding::kJpeg;
  opt.jpeg_quality = 95;
  depthfuse::color_frame_t msg;
  ASSERT_TRUE(lcm::encode_color_frame(smooth, opt, &msg).is_ok());
  ColorImage back;
  ASSERT_TRUE(lcm::decode_color_frame(msg, &back).is_ok());
  double err = 0;
  for (size_t i = 0; i < back.rgb.size(); ++i) err += std::abs(int(back.rgb[i]) - int(smooth.color.rgb[i]));
  EXPECT_LT(err / back.rgb.size(), 4.0);
  // Garbage JPEG is an error, not a crash.
  msg.data.assign(100, 0xff);
  msg.data_size = 100;
  EXPECT_EQ(lcm::decode_color_frame(msg, &back).code(), StatusCode::kCorrupt);
}

TEST(MessageDecoding, EveryTruncationIsMalformed) {
  const Frame f = make_frame(40, 30, 4);
  depthfuse::depth_frame_t msg;
  ASSERT_TRUE(lcm::encode_depth_frame(f, {}, &msg).is_ok());
  const auto bytes = lcm::encode_message(msg);
  for (size_t n = 0; n < bytes.size(); ++n) {
    depthfuse::depth_frame_t out;
    ASSERT_EQ(lcm::decode_message(bytes.data(), n, &out), DecodeResult::kMalformed) << n;
  }
  // Trailing bytes: two payloads glued together, or garbage after one.
  auto longer = bytes;
  longer.push_back(0);
  depthfuse::depth_frame_t out;
  EXPECT_EQ(lcm::decode_message(longer.data(), longer.size(), &out), DecodeResult::kMalformed);
}

TEST(MessageDecoding, RandomCorruptionNeverCrashes) {
  depthfuse::heartbeat_t hb{};
  hb.protocol_version = depthfuse::heartbeat_t::PROTOCOL_VERSION;
  hb.name = "fusion";
  hb.host = "host";
  hb.last_error = "none";
  hb.counters.resize(3);
  hb.num_counters = 3;
  for (auto& kv : hb.counters) kv.key = "k";
  const auto bytes = lcm::encode_message(hb);
  std::mt19937 rng(11);
  int ok = 0, malformed = 0, other = 0;
  for (int trial = 0; trial < 20000; ++trial) {
    auto b = bytes;
    const int flips = 1 + static_cast<int>(rng() % 4);
    for (int k = 0; k < flips; ++k) b[8 + rng() % (b.size() - 8)] = static_cast<uint8_t>(rng());
    depthfuse::heartbeat_t out;
    const auto r = lcm::decode_message(b.data(), b.size(), &out);
    if (r == DecodeResult::kOk) ++ok;
    else if (r == DecodeResult::kMalformed) ++malformed;
    else ++other;
  }
  EXPECT_GT(malformed, 0);
  EXPECT_EQ(ok + malformed + other, 20000);
}

TEST(MessageDecoding, HugeArrayLengthIsRejectedWithoutAllocating) {
  // data_size is the int32 right before the payload bytes: claim 2^31-1 bytes in a tiny message.
  Frame f = make_frame(8, 8, 1, false);
  depthfuse::depth_frame_t msg;
  ASSERT_TRUE(lcm::encode_depth_frame(f, {}, &msg).is_ok());
  auto bytes = lcm::encode_message(msg);
  const size_t data_pos = bytes.size() - (1 + 8 * 3 + 8 * 4) - msg.data.size() - 4;
  for (int32_t claim : {INT32_MAX, -1, INT32_MIN, 1 << 30}) {
    auto b = bytes;
    for (int k = 0; k < 4; ++k) b[data_pos + k] = static_cast<uint8_t>(uint32_t(claim) >> (24 - 8 * k));
    const int64_t rss_before = daemon::resident_memory_bytes();
    const auto t0 = std::chrono::steady_clock::now();
    depthfuse::depth_frame_t out;
    EXPECT_EQ(lcm::decode_message(b.data(), b.size(), &out), DecodeResult::kMalformed) << claim;
    const double ms = std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count();
    // Not a timing requirement: zeroing a 2 GiB vector would take ~1 s and show in the RSS.
    EXPECT_LT(daemon::resident_memory_bytes() - rss_before, 64 << 20) << claim;
    (void)ms;
  }
  // A string length of zero or below (std::string::assign would throw) is malformed too.
  depthfuse::command_t cmd{};
  cmd.protocol_version = 1;
  cmd.target = "fusion";
  auto cb = lcm::encode_message(cmd);
  const size_t target_len_pos = 8 + 2 + 8 + 8;
  for (int32_t claim : {0, -5}) {
    auto b = cb;
    for (int k = 0; k < 4; ++k) b[target_len_pos + k] = static_cast<uint8_t>(uint32_t(claim) >> (24 - 8 * k));
    depthfuse::command_t out;
    EXPECT_EQ(lcm::decode_message(b.data(), b.size(), &out), DecodeResult::kMalformed) << claim;
  }
}

TEST(MessageDecoding, ForeignTypeAndWrongVersionAreToldApart) {
  depthfuse::heartbeat_t hb{};
  hb.protocol_version = depthfuse::heartbeat_t::PROTOCOL_VERSION;
  const auto hb_bytes = lcm::encode_message(hb);
  depthfuse::depth_frame_t depth;
  EXPECT_EQ(lcm::decode_message(hb_bytes.data(), hb_bytes.size(), &depth), DecodeResult::kForeign);

  hb.protocol_version = 2;
  const auto v2 = lcm::encode_message(hb);
  depthfuse::heartbeat_t out;
  EXPECT_EQ(lcm::decode_message(v2.data(), v2.size(), &out), DecodeResult::kBadVersion);

  EXPECT_EQ(lcm::decode_message(nullptr, 0, &out), DecodeResult::kMalformed);
  const uint8_t few[3] = {1, 2, 3};
  EXPECT_EQ(lcm::decode_message(few, sizeof(few), &out), DecodeResult::kMalformed);

  lcm::ReceiveCounters c;
  c.count(DecodeResult::kOk);
  c.count(DecodeResult::kForeign);
  c.count(DecodeResult::kBadVersion);
  c.count(DecodeResult::kMalformed);
  c.count(DecodeResult::kMalformed);
  EXPECT_EQ(c.received.load(), 1);
  EXPECT_EQ(c.foreign.load(), 1);
  EXPECT_EQ(c.bad_version.load(), 1);
  EXPECT_EQ(c.malformed.load(), 2);
}

TEST(MessageDecoding, EveryTypeCarriesTheProtocolVersion) {
  EXPECT_EQ(depthfuse::depth_frame_t::PROTOCOL_VERSION, lcm::kProtocolVersion);
  EXPECT_EQ(depthfuse::color_frame_t::PROTOCOL_VERSION, lcm::kProtocolVersion);
  EXPECT_EQ(depthfuse::pose_t::PROTOCOL_VERSION, lcm::kProtocolVersion);
  EXPECT_EQ(depthfuse::pose2_t::PROTOCOL_VERSION, lcm::kProtocolVersion);
  EXPECT_EQ(depthfuse::heartbeat_t::PROTOCOL_VERSION, lcm::kProtocolVersion);
  EXPECT_EQ(depthfuse::status_t::PROTOCOL_VERSION, lcm::kProtocolVersion);
  EXPECT_EQ(depthfuse::command_t::PROTOCOL_VERSION, lcm::kProtocolVersion);
}

TEST(SequenceTracker, CountsGapsOutOfOrderAndRestarts) {
  lcm::SequenceTracker t(100);
  using V = lcm::SequenceTracker::Verdict;
  EXPECT_EQ(t.observe(10).verdict, V::kFirst);
  EXPECT_EQ(t.observe(11).verdict, V::kInOrder);
  auto gap = t.observe(15);
  EXPECT_EQ(gap.verdict, V::kGap);
  EXPECT_EQ(gap.lost, 3);
  EXPECT_EQ(t.observe(13).verdict, V::kOutOfOrder);
  EXPECT_EQ(t.observe(15).verdict, V::kOutOfOrder);  // a repeat
  EXPECT_EQ(t.observe(16).verdict, V::kInOrder);     // the late one did not move the reference
  EXPECT_EQ(t.observe(0).verdict, V::kOutOfOrder);   // 16 back: within the restart gap
  EXPECT_EQ(t.observe(80).lost, 63);                 // 63 ahead: within it, lost
  const auto far = t.observe(5000);                  // far ahead: a restart, nothing lost
  EXPECT_EQ(far.verdict, V::kRestart);
  EXPECT_EQ(far.lost, 0);
  EXPECT_EQ(t.observe(1).verdict, V::kRestart);      // far back: the sender restarted
  EXPECT_EQ(t.observe(2).verdict, V::kInOrder);
}

// Issue 36: one frame with the sequence + 2^31 made frames_lost read 2,147,484,502 for good. A jump
// beyond the restart gap, either way, is a restart: counted as such, never as lost frames.
TEST(SequenceTracker, AJumpOf2To31IsTwoRestartsNotTwoBillionLostFrames) {
  lcm::SequenceTracker t;
  lcm::ReceiveCounters counters;
  using V = lcm::SequenceTracker::Verdict;
  for (int64_t s = 1; s <= 100; ++s) counters.count(t.observe(s));
  const int64_t spoofed = 100 + (int64_t{1} << 31);
  const auto jump = t.observe(spoofed);
  counters.count(jump);
  EXPECT_EQ(jump.verdict, V::kRestart);
  const auto back = t.observe(101);  // the real stream goes on
  counters.count(back);
  EXPECT_EQ(back.verdict, V::kRestart);
  for (int64_t s = 102; s <= 110; ++s) {
    const auto seen = t.observe(s);
    counters.count(seen);
    EXPECT_EQ(seen.verdict, V::kInOrder) << s;
  }
  EXPECT_EQ(counters.lost.load(), 0);
  EXPECT_EQ(counters.sequence_restarts.load(), 2);
  EXPECT_EQ(counters.out_of_order.load(), 0);
  // The largest a message may carry (uint32), far ahead of a stream at 0: a restart as well.
  lcm::SequenceTracker u;
  u.observe(0);
  EXPECT_EQ(u.observe(0xFFFFFFFFll).lost, 0);
}

// One spoofed frame far ahead does not make the real stream late: three real frames in a row and
// the reference follows them, and the frames the jump counted as lost are taken back.
TEST(SequenceTracker, ResyncsAfterASpoofedJump) {
  lcm::SequenceTracker t(1000);
  using V = lcm::SequenceTracker::Verdict;
  for (int s = 1; s <= 100; ++s) t.observe(s);
  const auto spoof = t.observe(1100);
  EXPECT_EQ(spoof.verdict, V::kGap);
  EXPECT_EQ(spoof.lost, 999);
  EXPECT_EQ(t.observe(101).verdict, V::kOutOfOrder);
  EXPECT_EQ(t.observe(102).verdict, V::kOutOfOrder);
  const auto resync = t.observe(103);
  EXPECT_EQ(resync.verdict, V::kResync);
  EXPECT_EQ(spoof.lost + resync.lost, 0);  // nothing of the real stream was lost
  EXPECT_EQ(t.observe(104).verdict, V::kInOrder);
  // Late frames that are not a run stay late: 90, 95, 97 are each out of order.
  EXPECT_EQ(t.observe(90).verdict, V::kOutOfOrder);
  EXPECT_EQ(t.observe(95).verdict, V::kOutOfOrder);
  EXPECT_EQ(t.observe(97).verdict, V::kOutOfOrder);
  EXPECT_EQ(t.observe(105).verdict, V::kInOrder);
  // A run behind without a jump before it resyncs and takes nothing back.
  EXPECT_EQ(t.observe(50).verdict, V::kOutOfOrder);
  EXPECT_EQ(t.observe(51).verdict, V::kOutOfOrder);
  const auto back = t.observe(52);
  EXPECT_EQ(back.verdict, V::kResync);
  EXPECT_EQ(back.lost, 0);
}

TEST(PoseArrays, RoundTripAndRejectGarbage) {
  Pose T = Pose::Identity();
  T.linear() = Eigen::AngleAxisd(2.5, Eigen::Vector3d(0.2, -1, 0.4).normalized()).toRotationMatrix();
  T.translation() = Eigen::Vector3d(-3, 2, 0.5);
  double p[3], q[4];
  lcm::pose_to_arrays(T, p, q);
  auto back = lcm::pose_from_arrays(p, q);
  ASSERT_TRUE(back.is_ok());
  EXPECT_TRUE(back->isApprox(T, 1e-12));
  q[0] = std::nan("");
  EXPECT_FALSE(lcm::pose_from_arrays(p, q).is_ok());
}

}  // namespace
}  // namespace depthfuse
