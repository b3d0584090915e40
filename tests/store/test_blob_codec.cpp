// Blob encoding: lossless bit for bit, and every kind of damage is detected and named.
#include <gtest/gtest.h>

#include <cmath>
#include <limits>

#include "depthfuse/store/blob_codec.hpp"
#include "depthfuse/store/checksum.hpp"
#include "store_test_util.hpp"

using namespace depthfuse;
using namespace depthfuse::store;
using depthfuse::store::test::bit_equal;
using depthfuse::store::test::make_points;

TEST(Checksum, KnownVectors) {
  EXPECT_EQ(crc32("123456789", 9), 0xCBF43926u);
  EXPECT_EQ(crc32("", 0), 0u);
  // Running sums equal one pass, for every split (exercises the 8-byte path and the tail).
  const std::string text = "The quick brown fox jumps over the lazy dog, twice over.";
  for (size_t split = 0; split <= text.size(); ++split)
    EXPECT_EQ(crc32(text.data() + split, text.size() - split, crc32(text.data(), split)),
              crc32(text.data(), text.size()));
  EXPECT_EQ(crc32("The quick brown fox jumps over the lazy dog", 43), 0x414FA339u);
}

TEST(BlobCodec, PointsRoundTripBitExactIncludingSpecialFloats) {
  PointArrays a = make_points({3, -2, 7}, 5, 1000);
  // Values operator== cannot tell apart or never equals: -0, NaN with payload, inf, denormals.
  a.position_m[0].x() = -0.0f;
  a.position_m[1].y() = std::numeric_limits<float>::quiet_NaN();
  uint32_t nan_bits = 0x7FC0BEEFu;
  std::memcpy(&a.position_m[2].z(), &nan_bits, 4);
  a.state[3].nx = std::numeric_limits<float>::infinity();
  a.state[4].info_xx = std::numeric_limits<float>::denorm_min();
  a.state[5].merges = 65535;
  a.state[6].last_frame = 0xFFFFFFFFu;
  BlobCodec codec;
  std::vector<uint8_t> blob;
  ASSERT_TRUE(codec.encode_points(a, &blob));
  PointArrays b;
  ASSERT_TRUE(codec.decode_points(blob.data(), blob.size(), "chunk", &b));
  EXPECT_TRUE(bit_equal(a, b));
  EXPECT_LT(blob.size(), a.size() * PointArrays::kBytesPerPoint);  // it does compress
}

TEST(BlobCodec, EmptyChunkRoundTrips) {
  BlobCodec codec;
  std::vector<uint8_t> blob;
  ASSERT_TRUE(codec.encode_points(PointArrays{}, &blob));
  PointArrays b = make_points({0, 0, 0}, 1, 3);
  ASSERT_TRUE(codec.decode_points(blob.data(), blob.size(), "chunk", &b));
  EXPECT_EQ(b.size(), 0u);
}

TEST(BlobCodec, DepthPicksAnExactFormat) {
  const int w = 64, h = 48;
  BlobCodec codec;
  auto check = [&](const DepthImage& d, DepthFormat expected) {
    std::vector<uint8_t> blob;
    DepthFormat chosen{};
    ASSERT_TRUE(codec.encode_depth(d, &blob, &chosen));
    EXPECT_EQ(chosen, expected) << to_string(chosen);
    DepthImage back;
    ASSERT_TRUE(codec.decode_depth(blob.data(), blob.size(), "depth", &back));
    EXPECT_EQ(back.width, w);
    EXPECT_EQ(back.height, h);
    EXPECT_TRUE(test::same_bits(back.depth_m, d.depth_m));
  };
  DepthImage mm(w, h), tum(w, h), raw(w, h);
  for (int i = 0; i < w * h; ++i) {
    const uint16_t v = static_cast<uint16_t>(i % 7 == 0 ? 0 : 500 + (i * 37) % 4000);
    mm.depth_m[i] = static_cast<float>(v) / 1000.0f;      // a Kinect in millimetres
    tum.depth_m[i] = v ? static_cast<float>(v * 5 + 1) / 5000.0f : 0.0f;  // a TUM PNG (1/5000 m)
    raw.depth_m[i] = i % 7 == 0 ? 0.0f : 0.5f + 0.000123f * static_cast<float>(i);  // rendered
  }
  check(mm, DepthFormat::kU16DivBy1000);
  check(tum, DepthFormat::kU16DivBy5000);
  check(raw, DepthFormat::kFloat32);
  DepthImage nan = mm;
  nan.depth_m[10] = std::numeric_limits<float>::quiet_NaN();
  check(nan, DepthFormat::kFloat32);
  // The encoder checks blocks of pixels at a time: what cannot round-trip must be caught in the
  // last pixel too, and the range's ends must hold.
  DepthImage ends = mm;
  ends.depth_m[w * h - 2] = 65535.0f / 1000.0f;
  check(ends, DepthFormat::kU16DivBy1000);
  for (float bad : {65536.0f / 1000.0f, -0.001f, -0.0f, 1e30f}) {
    DepthImage d = mm;
    d.depth_m[w * h - 1] = bad;
    check(d, DepthFormat::kFloat32);
  }
}

TEST(BlobCodec, ColorRoundTrips) {
  ColorImage c;
  c.width = 17;
  c.height = 9;
  for (int i = 0; i < 17 * 9 * 3; ++i) c.rgb.push_back(static_cast<uint8_t>(i * 31));
  BlobCodec codec;
  std::vector<uint8_t> blob;
  ASSERT_TRUE(codec.encode_color(c, &blob));
  ColorImage back;
  ASSERT_TRUE(codec.decode_color(blob.data(), blob.size(), "colour", &back));
  EXPECT_EQ(back.rgb, c.rgb);
  // The frame log's fast colour level: still lossless.
  BlobCodec fast(1, -5);
  ASSERT_TRUE(fast.encode_color(c, &blob));
  ASSERT_TRUE(fast.decode_color(blob.data(), blob.size(), "colour", &back));
  EXPECT_EQ(back.rgb, c.rgb);
}

TEST(BlobCodec, EveryDamagedByteIsDetected) {
  const PointArrays a = make_points({1, 1, 1}, 2, 300);
  BlobCodec codec;
  std::vector<uint8_t> blob;
  ASSERT_TRUE(codec.encode_points(a, &blob));
  // Flip each bit in turn: decoding fails with a message naming the blob, or (a bit zstd does
  // not use) returns the original data. Never a crash, never wrong data.
  size_t detected = 0, harmless = 0;
  for (size_t i = 0; i < blob.size(); ++i) {
    for (int bit = 0; bit < 8; ++bit) {
      std::vector<uint8_t> bad = blob;
      bad[i] ^= static_cast<uint8_t>(1u << bit);
      PointArrays out;
      Status st = codec.decode_points(bad.data(), bad.size(), "chunk (1,1,1)", &out);
      if (st) {
        EXPECT_TRUE(bit_equal(out, a)) << "byte " << i << " bit " << bit << " gave wrong data";
        ++harmless;
        continue;
      }
      ++detected;
      EXPECT_EQ(st.code(), StatusCode::kCorrupt);
      EXPECT_NE(st.message().find("chunk (1,1,1)"), std::string::npos) << st.message();
    }
  }
  EXPECT_GT(detected, 0u);
  EXPECT_LT(harmless, blob.size() / 100 + 8) << "too many flips have no effect";
}

TEST(BlobCodec, DamageIsNamed) {
  const PointArrays a = make_points({1, 1, 1}, 2, 300);
  BlobCodec codec;
  std::vector<uint8_t> blob;
  ASSERT_TRUE(codec.encode_points(a, &blob));
  PointArrays out;
  // Header byte: the header checksum.
  std::vector<uint8_t> bad = blob;
  bad[9] ^= 0xFF;
  Status st = codec.decode_points(bad.data(), bad.size(), "c", &out);
  EXPECT_NE(st.message().find("header checksum"), std::string::npos) << st.message();
  // Truncated.
  st = codec.decode_points(blob.data(), blob.size() - 10, "c", &out);
  EXPECT_NE(st.message().find("truncated"), std::string::npos) << st.message();
  // Not a blob at all.
  const char junk[64] = "this is not a blob, just some text that is long enough....";
  st = codec.decode_points(junk, sizeof(junk), "c", &out);
  EXPECT_NE(st.message().find("bad magic"), std::string::npos) << st.message();
  // A wrong kind.
  DepthImage d(8, 8);
  std::vector<uint8_t> depth;
  ASSERT_TRUE(codec.encode_depth(d, &depth));
  st = codec.decode_points(depth.data(), depth.size(), "c", &out);
  EXPECT_NE(st.message().find("expected a points blob"), std::string::npos) << st.message();
}

TEST(BlobCodec, PoseRoundTripsExactly) {
  Pose T = Pose::Identity();
  T.linear() = Eigen::AngleAxisd(0.3, Eigen::Vector3d(1, 2, 3).normalized()).toRotationMatrix();
  T.translation() = Eigen::Vector3d(1.0 / 3.0, -2e-7, 12345.678);
  const auto blob = encode_pose(T);
  Pose back;
  ASSERT_TRUE(decode_pose(blob.data(), blob.size(), "pose", &back));
  EXPECT_EQ(std::memcmp(back.matrix().data(), T.matrix().data(), sizeof(double) * 16), 0);
  EXPECT_FALSE(decode_pose(blob.data(), blob.size() - 1, "pose", &back));
  auto bad = blob;
  bad[7] ^= 0x40;  // an exponent bit of R(0,0): the rotation stops being orthonormal
  EXPECT_FALSE(decode_pose(bad.data(), bad.size(), "pose", &back));
}
