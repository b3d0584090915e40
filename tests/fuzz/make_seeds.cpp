// Writes a seed corpus for each fuzz target: valid inputs the fuzzer mutates from, so that it
// starts past the fingerprints and magic numbers instead of guessing them.
//   make_seeds <corpus-root>   -> <corpus-root>/<target>/* for every target
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <string>
#include <vector>

#include "depthfuse/command_t.hpp"
#include "depthfuse/heartbeat_t.hpp"
#include "depthfuse/lcm/codec.hpp"
#include "depthfuse/lcm/frame_codec.hpp"
#include "depthfuse/lcm/udpm.hpp"
#include "depthfuse/ply.hpp"
#include "depthfuse/pose2_t.hpp"
#include "depthfuse/pose_t.hpp"
#include "depthfuse/store/blob_codec.hpp"

#include <opencv2/imgcodecs.hpp>

namespace fs = std::filesystem;
using Bytes = std::vector<uint8_t>;

namespace {

void write(const fs::path& dir, const std::string& name, const Bytes& bytes) {
  fs::create_directories(dir);
  std::ofstream(dir / name, std::ios::binary)
      .write(reinterpret_cast<const char*>(bytes.data()), static_cast<std::streamsize>(bytes.size()));
}

void put(Bytes* out, uint64_t v, int bytes) {
  for (int i = bytes - 1; i >= 0; --i) out->push_back(static_cast<uint8_t>(v >> (8 * i)));
}

// One datagram in fuzz_udpm's framing: length, sender, bytes.
void framed(Bytes* out, const Bytes& datagram, uint8_t sender) {
  put(out, datagram.size(), 2);
  out->push_back(sender);
  out->insert(out->end(), datagram.begin(), datagram.end());
}

// `payload` on `channel` as liblcm sends it, cut into fragments of at most `room` bytes.
Bytes as_datagrams(const std::string& channel, const Bytes& payload, size_t room, uint8_t sender) {
  namespace udpm = depthfuse::lcm::udpm;
  Bytes out;
  if (channel.size() + 1 + payload.size() + udpm::kShortHeaderBytes <= room) {
    Bytes d;
    put(&d, udpm::kShortMagic, 4);
    put(&d, 1, 4);
    d.insert(d.end(), channel.begin(), channel.end());
    d.push_back(0);
    d.insert(d.end(), payload.begin(), payload.end());
    framed(&out, d, sender);
    return out;
  }
  const size_t first = room - udpm::kFragmentHeaderBytes - channel.size() - 1;
  const size_t rest = room - udpm::kFragmentHeaderBytes;
  const size_t count = 1 + (payload.size() > first ? (payload.size() - first + rest - 1) / rest : 0);
  size_t offset = 0;
  for (size_t i = 0; i < count; ++i) {
    const size_t n = std::min(i == 0 ? first : rest, payload.size() - offset);
    Bytes d;
    put(&d, udpm::kFragmentMagic, 4);
    put(&d, 2, 4);
    put(&d, payload.size(), 4);
    put(&d, offset, 4);
    put(&d, i, 2);
    put(&d, count, 2);
    if (i == 0) {
      d.insert(d.end(), channel.begin(), channel.end());
      d.push_back(0);
    }
    d.insert(d.end(), payload.begin() + static_cast<std::ptrdiff_t>(offset),
             payload.begin() + static_cast<std::ptrdiff_t>(offset + n));
    framed(&out, d, sender);
    offset += n;
  }
  return out;
}

}  // namespace

int main(int argc, char** argv) {
  using namespace depthfuse;
  if (argc != 2) {
    std::fprintf(stderr, "usage: make_seeds <corpus-root>\n");
    return 2;
  }
  const fs::path root = argv[1];

  Frame frame;
  frame.intrinsics = CameraIntrinsics::kinect_v2();
  frame.intrinsics.width = 32;
  frame.intrinsics.height = 24;
  frame.intrinsics.cx = 15.5;
  frame.intrinsics.cy = 11.5;
  frame.depth = DepthImage(32, 24);
  for (size_t i = 0; i < frame.depth.depth_m.size(); ++i) frame.depth.depth_m[i] = 0.8f + 0.001f * (i % 50);
  frame.color.width = 32;
  frame.color.height = 24;
  frame.color.rgb.assign(32 * 24 * 3, 128);
  std::vector<std::pair<std::string, Bytes>> messages;
  for (bool compress : {false, true}) {
    depth_frame_t depth;
    lcm::DepthEncodeOptions options;
    options.compress = compress;
    if (!lcm::encode_depth_frame(frame, options, &depth).is_ok()) return 1;
    messages.emplace_back(compress ? "depth_zstd" : "depth_raw", lcm::encode_message(depth));
  }
  for (auto encoding : {lcm::ColorEncoding::kRaw, lcm::ColorEncoding::kZstd, lcm::ColorEncoding::kJpeg}) {
    color_frame_t color;
    lcm::ColorEncodeOptions options;
    options.encoding = encoding;
    if (!lcm::encode_color_frame(frame, options, &color).is_ok()) return 1;
    messages.emplace_back("color_" + std::to_string(static_cast<int>(encoding)), lcm::encode_message(color));
  }
  pose_t pose{};
  pose.protocol_version = pose_t::PROTOCOL_VERSION;
  pose.orientation_wxyz[0] = 1;
  messages.emplace_back("pose", lcm::encode_message(pose));
  pose2_t pose2{};
  pose2.protocol_version = pose2_t::PROTOCOL_VERSION;
  pose2.tracking = pose2_t::TRACKING_LOST;
  pose2.pose = pose;
  messages.emplace_back("pose2", lcm::encode_message(pose2));
  command_t command{};
  command.protocol_version = command_t::PROTOCOL_VERSION;
  command.action = command_t::ACTION_START;
  command.target = "fusion";
  command.argument = "scan";
  command.sender = "fuzz@seed";
  messages.emplace_back("command", lcm::encode_message(command));
  heartbeat_t heartbeat{};
  heartbeat.protocol_version = heartbeat_t::PROTOCOL_VERSION;
  heartbeat.name = "fusion";
  messages.emplace_back("heartbeat", lcm::encode_message(heartbeat));

  for (const auto& [name, bytes] : messages) {
    write(root / "fuzz_lcm_messages", name, bytes);
    write(root / "fuzz_udpm", name, as_datagrams("DEPTHFUSE_" + name, bytes, 600, 1));
  }

  // Files: a PLY of a few points, a 64x48 depth PNG, the shipped config, and each kind of blob
  // (its first byte picks the decoder in fuzz_store_blobs).
  PointArrays points;
  for (int i = 0; i < 5; ++i) {
    PointRecord r;
    r.position_m = {0.1f * i, 0.2f, 1.0f};
    r.merges = static_cast<uint16_t>(i);
    points.push_back(r);
  }
  fs::create_directories(root / "fuzz_ply");
  if (!write_ply((root / "fuzz_ply" / "five.ply").string(), points).is_ok()) return 1;
  fs::create_directories(root / "fuzz_tum_png");
  cv::Mat depth(48, 64, CV_16UC1, cv::Scalar(10000));
  if (!cv::imwrite((root / "fuzz_tum_png" / "flat.png").string(), depth)) return 1;
  fs::create_directories(root / "fuzz_config");
  fs::copy_file(DEPTHFUSE_CONFIG_FILE, root / "fuzz_config" / "depthfuse.toml",
                fs::copy_options::overwrite_existing);
  store::BlobCodec codec(1);
  auto blob_seed = [&](uint8_t which, const std::string& name, const Bytes& blob) {
    Bytes b{which};
    b.insert(b.end(), blob.begin(), blob.end());
    write(root / "fuzz_store_blobs", name, b);
  };
  Bytes blob;
  if (!codec.encode_points(points, &blob).is_ok()) return 1;
  blob_seed(0, "points", blob);
  if (!codec.encode_depth(frame.depth, &blob).is_ok()) return 1;
  blob_seed(1, "depth", blob);
  if (!codec.encode_color(frame.color, &blob).is_ok()) return 1;
  blob_seed(2, "color", blob);
  Pose pose_seed = Pose::Identity();
  pose_seed.translation() = Eigen::Vector3d(0.5, -0.25, 1.0);
  blob_seed(3, "pose", store::encode_pose(pose_seed));
  return 0;
}
