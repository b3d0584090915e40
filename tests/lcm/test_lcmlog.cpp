// Sessions recorded by lcm-logger as a FrameSource: frames and colour come back exactly, unusable
// events are counted, truncated and damaged logs are read up to (and past) the damage.
#include <gtest/gtest.h>
#include <lcm/eventlog.h>

#include <cstdio>
#include <filesystem>
#include <fstream>
#include <optional>

#include "depthfuse/color_frame_t.hpp"
#include "depthfuse/depth_frame_t.hpp"
#include "depthfuse/heartbeat_t.hpp"
#include "depthfuse/lcm/channels.hpp"
#include "depthfuse/lcm/codec.hpp"
#include "depthfuse/lcm/frame_codec.hpp"
#include "depthfuse/lcm/message_auth.hpp"
#include "depthfuse/lcmlog/lcmlog_source.hpp"
#include "depthfuse/source_factory.hpp"
#include "lcm_test_util.hpp"

namespace depthfuse {
namespace {

Frame test_frame(uint32_t seq, int width = 48, int height = 40) {
  Frame f;
  f.utime = 1'000'000 + seq * 33'333;
  f.sequence = seq;
  f.sensor_serial = "log";
  f.intrinsics.width = width;
  f.intrinsics.height = height;
  f.intrinsics.cx = (width - 1) / 2.0;  // the principal point inside the image, as receivers require
  f.intrinsics.cy = (height - 1) / 2.0;
  f.depth = DepthImage(width, height);
  for (size_t i = 0; i < f.depth.depth_m.size(); ++i)
    f.depth.depth_m[i] = static_cast<float>((800 + (i * 7 + seq) % 2000) * 0.001);
  f.color.width = width;
  f.color.height = height;
  f.color.rgb.assign(static_cast<size_t>(width) * height * 3, static_cast<uint8_t>(seq * 10));
  return f;
}

class LogWriter {
 public:
  explicit LogWriter(const std::string& path) : log_(lcm_eventlog_create(path.c_str(), "w")) {}
  ~LogWriter() {
    if (log_) lcm_eventlog_destroy(log_);
  }
  bool ok() const { return log_ != nullptr; }
  // What a rig with a key records: every message with its signature (message_auth.hpp).
  void sign_with(const lcm::RigKey& key) { auth_.emplace(key, 1'000'000); }
  void write(const std::string& channel, std::vector<uint8_t> data, int64_t utime) {
    if (auth_) {
      const size_t n = data.size();
      data.resize(n + lcm::kSignatureBytes);
      auth_->sign(channel, data.data(), n, utime, data.data() + n);
    }
    lcm_eventlog_event_t ev{};
    ev.timestamp = utime;
    ev.channellen = static_cast<int32_t>(channel.size());
    ev.datalen = static_cast<int32_t>(data.size());
    ev.channel = const_cast<char*>(channel.c_str());
    ev.data = const_cast<uint8_t*>(data.data());
    lcm_eventlog_write_event(log_, &ev);
  }
  void write_frame(const Frame& f) {
    depthfuse::color_frame_t c;
    ASSERT_TRUE(lcm::encode_color_frame(f, {}, &c).is_ok());
    write(lcm::kColorChannel, lcm::encode_message(c), f.utime);
    depthfuse::depth_frame_t d;
    ASSERT_TRUE(lcm::encode_depth_frame(f, {}, &d).is_ok());
    write(lcm::kDepthChannel, lcm::encode_message(d), f.utime + 100);
  }

 private:
  lcm_eventlog_t* log_;
  std::optional<lcm::MessageAuth> auth_;
};

// A log of 5 good frames with unusable events in between.
std::string write_mixed_log(const std::string& dir) {
  const std::string path = dir + "/mixed.lcmlog";
  LogWriter w(path);
  EXPECT_TRUE(w.ok());
  for (uint32_t i = 0; i < 5; ++i) {
    w.write_frame(test_frame(i));
    if (i == 1) {
      depthfuse::heartbeat_t hb{};
      hb.protocol_version = 1;
      w.write(lcm::kDepthChannel, lcm::encode_message(hb), 5);  // foreign type
      w.write(lcm::kHeartbeatChannel, lcm::encode_message(hb), 6);  // not a frame channel: ignored
    }
    if (i == 2) {
      depthfuse::depth_frame_t d;
      EXPECT_TRUE(lcm::encode_depth_frame(test_frame(99), {}, &d).is_ok());
      d.protocol_version = 7;
      w.write(lcm::kDepthChannel, lcm::encode_message(d), 7);  // unknown version
      auto bytes = lcm::encode_message(d);
      bytes.resize(bytes.size() / 2);
      w.write(lcm::kDepthChannel, bytes, 8);  // truncated message
    }
  }
  return path;
}

TEST(LcmLogSource, ReadsFramesAndCountsUnusableEvents) {
  const std::string dir = testing::temp_dir("lcmlog");
  const std::string path = write_mixed_log(dir);
  auto src = lcmlog::LcmLogSource::open(path, {});
  ASSERT_TRUE(src.is_ok()) << src.status().to_string();
  const auto& s = (*src)->stats();
  EXPECT_EQ(s.depth_frames, 5u);
  EXPECT_EQ(s.color_frames, 5u);
  EXPECT_EQ(s.foreign, 1u);
  EXPECT_EQ(s.bad_version, 1u);
  EXPECT_EQ(s.malformed, 1u);
  EXPECT_FALSE(s.truncated);
  EXPECT_EQ((*src)->frame_count().value_or(0), 5u);
  ASSERT_TRUE((*src)->nominal_rate_hz().has_value());
  EXPECT_NEAR(*(*src)->nominal_rate_hz(), 30.0, 0.1);
  for (uint32_t i = 0; i < 5; ++i) {
    auto f = (*src)->next();
    ASSERT_TRUE(f.is_ok()) << f.status().to_string();
    const Frame want = test_frame(i);
    EXPECT_EQ(f->sequence, i);
    EXPECT_EQ(f->utime, want.utime);
    EXPECT_EQ(f->depth.depth_m, want.depth.depth_m);
    EXPECT_EQ(f->color.rgb, want.color.rgb);
  }
  EXPECT_EQ((*src)->next().status().code(), StatusCode::kEndOfStream);
  ASSERT_TRUE((*src)->rewind().is_ok());
  EXPECT_EQ((*src)->next()->sequence, 0u);
}

TEST(LcmLogSource, ReadsARigsSignedRecording) {
  const std::string path = testing::temp_dir("lcmlog-signed") + "/signed.lcmlog";
  {
    LogWriter w(path);
    ASSERT_TRUE(w.ok());
    w.sign_with(lcm::RigKey::from_bytes({}));
    for (uint32_t i = 0; i < 3; ++i) w.write_frame(test_frame(i));
  }
  auto src = lcmlog::LcmLogSource::open(path, {});
  ASSERT_TRUE(src.is_ok()) << src.status().to_string();
  EXPECT_EQ((*src)->stats().depth_frames, 3u);
  EXPECT_EQ((*src)->stats().malformed, 0u);
  for (uint32_t i = 0; i < 3; ++i) {
    auto f = (*src)->next();
    ASSERT_TRUE(f.is_ok()) << f.status().to_string();
    EXPECT_EQ(f->depth.depth_m, test_frame(i).depth.depth_m);
    EXPECT_EQ(f->color.rgb, test_frame(i).color.rgb);
  }
}

TEST(LcmLogSource, OpensThroughTheFactory) {
  const std::string dir = testing::temp_dir("lcmlog-factory");
  const std::string path = write_mixed_log(dir);
  auto src = open_frame_source("lcmlog:" + path, AppConfig{});
  ASSERT_TRUE(src.is_ok()) << src.status().to_string();
  EXPECT_EQ((*src)->frame_count().value_or(0), 5u);
  EXPECT_NE((*src)->describe().find("lcmlog:"), std::string::npos);
  auto bad = open_frame_source("lcmlog:" + path + "?colour=x", AppConfig{});
  EXPECT_EQ(bad.status().code(), StatusCode::kInvalidArgument);
  auto other = open_frame_source("lcmlog:" + path + "?depth_channel=ELSEWHERE", AppConfig{});
  EXPECT_EQ(other.status().code(), StatusCode::kCorrupt);
  EXPECT_NE(other.status().message().find("ELSEWHERE"), std::string::npos);
}

TEST(LcmLogSource, TakesTheConfiguredFrameLimits) {
  // A log of 800x600 frames: beyond the default limits (640x480), within a rig's configured ones;
  // and the 48x40 frames of the mixed log beyond a configured 40 px width.
  const std::string dir = testing::temp_dir("lcmlog-limits");
  const std::string large = dir + "/large.lcmlog";
  {
    LogWriter w(large);
    ASSERT_TRUE(w.ok());
    for (uint32_t i = 0; i < 2; ++i) w.write_frame(test_frame(i, 800, 600));
  }
  auto refused = open_frame_source("lcmlog:" + large, AppConfig{});
  EXPECT_EQ(refused.status().code(), StatusCode::kCorrupt);
  EXPECT_NE(refused.status().message().find("800x600"), std::string::npos)
      << refused.status().message();
  AppConfig wide;
  wide.fusion.max_frame_width = 800;
  wide.fusion.max_frame_height = 600;
  auto taken = open_frame_source("lcmlog:" + large, wide);
  ASSERT_TRUE(taken.is_ok()) << taken.status().to_string();
  auto f = (*taken)->next();
  ASSERT_TRUE(f.is_ok()) << f.status().to_string();
  EXPECT_EQ(f->depth.width, 800);
  EXPECT_EQ(f->color.width, 800);

  AppConfig narrow;
  narrow.fusion.max_frame_width = 40;
  auto small = open_frame_source("lcmlog:" + write_mixed_log(dir), narrow);
  EXPECT_EQ(small.status().code(), StatusCode::kCorrupt);
  EXPECT_NE(small.status().message().find("48x40"), std::string::npos) << small.status().message();
}

TEST(LcmLogSource, TruncatedLogEndsAtTheLastCompleteEvent) {
  const std::string dir = testing::temp_dir("lcmlog-trunc");
  const std::string path = write_mixed_log(dir);
  const auto full = std::filesystem::file_size(path);
  // Cut at many points: never a crash, frames up to the cut.
  size_t last_frames = 0;
  for (int k = 1; k <= 40; ++k) {
    const std::string cut = dir + "/cut.lcmlog";
    std::filesystem::copy_file(path, cut, std::filesystem::copy_options::overwrite_existing);
    const auto size = full * k / 41;
    std::filesystem::resize_file(cut, size);
    auto src = lcmlog::LcmLogSource::open(cut, {});
    if (!src.is_ok()) {
      EXPECT_EQ(src.status().code(), StatusCode::kCorrupt) << src.status().to_string();
      continue;
    }
    const size_t frames = (*src)->frame_count().value_or(0);
    EXPECT_GE(frames, last_frames);
    last_frames = frames;
    for (size_t i = 0; i < frames; ++i) ASSERT_TRUE((*src)->next().is_ok());
  }
  EXPECT_GE(last_frames, 4u);
}

TEST(LcmLogSource, SkipsDamagedBytesToTheNextEvent) {
  const std::string dir = testing::temp_dir("lcmlog-damage");
  const std::string path = write_mixed_log(dir);
  // Overwrite bytes in the middle (a header, most likely): later events are still found.
  std::string bytes = testing::read_text(path);
  const size_t mid = bytes.size() / 2;
  for (size_t i = mid; i < mid + 64 && i < bytes.size(); ++i) bytes[i] = '\xee';
  // And a bogus header claiming a 2 GB event and a 5000-byte channel name at the start of a copy.
  const std::string damaged = dir + "/damaged.lcmlog";
  {
    std::ofstream out(damaged, std::ios::binary);
    const unsigned char bogus[28] = {0xED, 0xA1, 0xDA, 0x01, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0,
                                     0, 0, 0, 0, 0, 0, 0, 0, 0x13, 0x88, 0x7f, 0xff, 0xff, 0xff};
    out.write(reinterpret_cast<const char*>(bogus), sizeof(bogus));
    out << bytes;
  }
  auto src = lcmlog::LcmLogSource::open(damaged, {});
  ASSERT_TRUE(src.is_ok()) << src.status().to_string();
  EXPECT_GE((*src)->stats().corrupt_regions, 1u);
  EXPECT_GE((*src)->frame_count().value_or(0), 3u);
  EXPECT_LE((*src)->frame_count().value_or(0), 5u);
  while (true) {
    auto f = (*src)->next();
    if (!f.is_ok()) {
      EXPECT_EQ(f.status().code(), StatusCode::kEndOfStream);
      break;
    }
  }
}

TEST(LcmLogSource, NotALogIsAClearError) {
  const std::string dir = testing::temp_dir("lcmlog-garbage");
  const std::string path = dir + "/garbage.lcmlog";
  {
    std::ofstream out(path, std::ios::binary);
    for (int i = 0; i < 10000; ++i) out.put(static_cast<char>(i * 37));
  }
  auto src = lcmlog::LcmLogSource::open(path, {});
  ASSERT_FALSE(src.is_ok());
  EXPECT_NE(src.status().message().find("no usable depth frames"), std::string::npos)
      << src.status().to_string();
  auto missing = lcmlog::LcmLogSource::open(dir + "/missing.lcmlog", {});
  EXPECT_EQ(missing.status().code(), StatusCode::kNotFound);
}

}  // namespace
}  // namespace depthfuse
