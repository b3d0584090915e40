#include "depthfuse/lcm/frame_codec.hpp"

#include <zstd.h>

#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <limits>
#include <optional>
#include <utility>
#include <opencv2/core.hpp>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>

#include "depthfuse/base/delta16.hpp"

namespace depthfuse::lcm {

namespace {

using Clock = std::chrono::steady_clock;
double ms_since(Clock::time_point t0) {
  return std::chrono::duration<double, std::milli>(Clock::now() - t0).count();
}


inline uint16_t depth_to_count(float depth_m, double inv_unit) {
  if (!(depth_m > 0.0f)) return 0;  // also NaN
  const double c = std::nearbyint(static_cast<double>(depth_m) * inv_unit);
  return c >= 1.0 && c <= 65535.0 ? static_cast<uint16_t>(c) : 0;
}

inline float count_to_depth(uint16_t count, double unit_m) {
  return static_cast<float>(count * unit_m);
}

// uint16 to little-endian bytes (the wire layout on every host).
void store_le16(const std::vector<uint16_t>& in, uint8_t* out) {
  for (size_t i = 0; i < in.size(); ++i) {
    out[2 * i] = static_cast<uint8_t>(in[i] & 0xff);
    out[2 * i + 1] = static_cast<uint8_t>(in[i] >> 8);
  }
}

// The row predictor of ENCODING_ZSTD_DELTA_UINT16 (see depth_frame_t.lcm): each row on its own,
// zigzagged, into byte planes (the scan file's depth blobs share the transform, over the whole
// image).
Delta16Layout row_predictor(int width) { return Delta16Layout{static_cast<size_t>(width), true}; }

Status zstd_compress(const uint8_t* src, size_t size, int level, std::vector<uint8_t>* out) {
  out->resize(ZSTD_compressBound(size));
  const size_t n = ZSTD_compress(out->data(), out->size(), src, size, level);
  if (ZSTD_isError(n)) return internal_error(std::string("zstd: ") + ZSTD_getErrorName(n));
  out->resize(n);
  return Status::ok();
}

// Inflates exactly `expected` bytes or fails: the declared content size must match too.
Status zstd_decompress(const uint8_t* src, size_t size, size_t expected, std::vector<uint8_t>* out,
                       const char* what) {
  const unsigned long long declared = ZSTD_getFrameContentSize(src, size);
  if (declared == ZSTD_CONTENTSIZE_ERROR)
    return corrupt(std::string(what) + ": the zstd data is not a zstd frame");
  if (declared != ZSTD_CONTENTSIZE_UNKNOWN && declared != expected)
    return corrupt(std::string(what) + ": zstd data inflates to " + std::to_string(declared) +
                   " bytes, the image needs " + std::to_string(expected));
  out->resize(expected);
  const size_t n = ZSTD_decompress(out->data(), expected, src, size);
  if (ZSTD_isError(n))
    return corrupt(std::string(what) + ": zstd: " + ZSTD_getErrorName(n));
  if (n != expected)
    return corrupt(std::string(what) + ": zstd data inflated to " + std::to_string(n) +
                   " bytes, the image needs " + std::to_string(expected));
  return Status::ok();
}

bool finite_all(const double* v, int n) {
  for (int i = 0; i < n; ++i)
    if (!std::isfinite(v[i])) return false;
  return true;
}

}  // namespace

void pose_to_arrays(const Pose& T, double position_m[3], double orientation_wxyz[4]) {
  const Eigen::Vector3d t = T.translation();
  const Eigen::Quaterniond q(T.rotation());
  for (int i = 0; i < 3; ++i) position_m[i] = t[i];
  orientation_wxyz[0] = q.w();
  orientation_wxyz[1] = q.x();
  orientation_wxyz[2] = q.y();
  orientation_wxyz[3] = q.z();
}

Result<Pose> pose_from_arrays(const double position_m[3], const double orientation_wxyz[4]) {
  if (!finite_all(position_m, 3) || !finite_all(orientation_wxyz, 4))
    return corrupt("pose has non-finite values");
  Eigen::Quaterniond q(orientation_wxyz[0], orientation_wxyz[1], orientation_wxyz[2],
                       orientation_wxyz[3]);
  if (q.norm() < 1e-6) return corrupt("pose orientation is not a rotation (zero quaternion)");
  q.normalize();
  Pose T = Pose::Identity();
  T.linear() = q.toRotationMatrix();
  T.translation() = Eigen::Vector3d(position_m[0], position_m[1], position_m[2]);
  return T;
}

Status encode_depth_frame(const Frame& frame, const DepthEncodeOptions& options,
                          depthfuse::depth_frame_t* out, CodecTiming* timing) {
  const DepthImage& d = frame.depth;
  if (d.width <= 0 || d.height <= 0 || d.depth_m.size() != static_cast<size_t>(d.width) * d.height)
    return invalid_argument("depth image is empty or its size does not match its dimensions");
  if (!(options.depth_unit_m > 0.0) || !std::isfinite(options.depth_unit_m))
    return invalid_argument("depth_unit_m must be positive");

  out->protocol_version = depthfuse::depth_frame_t::PROTOCOL_VERSION;
  out->utime = frame.utime;
  out->publish_utime = 0;
  out->sequence = frame.sequence;
  out->sensor_serial = frame.sensor_serial;
  out->intrinsics.width = frame.intrinsics.width;
  out->intrinsics.height = frame.intrinsics.height;
  out->intrinsics.fx = frame.intrinsics.fx;
  out->intrinsics.fy = frame.intrinsics.fy;
  out->intrinsics.cx = frame.intrinsics.cx;
  out->intrinsics.cy = frame.intrinsics.cy;
  out->depth_unit_m = options.depth_unit_m;

  auto t0 = Clock::now();
  const size_t n = d.depth_m.size();
  thread_local std::vector<uint16_t> counts;
  thread_local std::vector<uint8_t> raw;
  counts.resize(n);
  const double inv_unit = 1.0 / options.depth_unit_m;
  for (size_t i = 0; i < n; ++i) counts[i] = depth_to_count(d.depth_m[i], inv_unit);
  if (timing) timing->convert_ms += ms_since(t0);

  t0 = Clock::now();
  if (options.compress) {
    raw.resize(2 * n);
    if (options.predict_rows) {
      delta16_to_planes(counts.data(), n, row_predictor(d.width), raw.data());
      out->encoding = depthfuse::depth_frame_t::ENCODING_ZSTD_DELTA_UINT16;
    } else {
      store_le16(counts, raw.data());
      out->encoding = depthfuse::depth_frame_t::ENCODING_ZSTD_UINT16;
    }
    DF_RETURN_IF_ERROR(zstd_compress(raw.data(), raw.size(), options.zstd_level, &out->data));
  } else {
    out->data.resize(2 * n);
    store_le16(counts, out->data.data());
    out->encoding = depthfuse::depth_frame_t::ENCODING_RAW_UINT16;
  }
  out->data_size = static_cast<int32_t>(out->data.size());
  if (timing && options.compress) timing->compress_ms += ms_since(t0);

  out->has_pose_hint = frame.T_world_cam_hint.has_value();
  if (frame.T_world_cam_hint) {
    pose_to_arrays(*frame.T_world_cam_hint, out->hint_position_m, out->hint_orientation_wxyz);
  } else {
    for (double& v : out->hint_position_m) v = 0;
    out->hint_orientation_wxyz[0] = 1;
    out->hint_orientation_wxyz[1] = out->hint_orientation_wxyz[2] = out->hint_orientation_wxyz[3] = 0;
  }
  return Status::ok();
}

namespace {

// A JPEG's width and height from its frame header (SOFn), without decoding it; nothing if the
// data ends or the scan starts before one. OpenCV allocates for the size the JPEG declares before
// it decodes a byte, so a few hundred bytes could claim gigabytes.
std::optional<std::pair<int, int>> jpeg_size(const uint8_t* p, size_t n) {
  if (n < 4 || p[0] != 0xFF || p[1] != 0xD8) return std::nullopt;
  size_t i = 2;
  while (i + 4 <= n) {
    if (p[i] != 0xFF) return std::nullopt;
    const uint8_t marker = p[i + 1];
    if (marker == 0xFF) {  // fill byte
      ++i;
      continue;
    }
    if (marker == 0x01 || (marker >= 0xD0 && marker <= 0xD7)) {  // no length
      i += 2;
      continue;
    }
    const size_t length = (size_t{p[i + 2]} << 8) | p[i + 3];
    const bool frame_header = marker >= 0xC0 && marker <= 0xCF && marker != 0xC4 &&
                              marker != 0xC8 && marker != 0xCC;
    if (frame_header) {
      if (length < 7 || i + 9 > n) return std::nullopt;
      const int height = (p[i + 5] << 8) | p[i + 6], width = (p[i + 7] << 8) | p[i + 8];
      return std::make_pair(width, height);
    }
    if (marker == 0xDA || length < 2) return std::nullopt;  // the scan, before any frame header
    i += 2 + length;
  }
  return std::nullopt;
}

// Refuses an image larger than the receiver's sensors, or not an image at all.
Status check_image_size(int width, int height, const FrameLimits& limits, const std::string& what) {
  if (width <= 0 || height <= 0)
    return corrupt(what + ": image size " + std::to_string(width) + "x" + std::to_string(height) +
                   " is not positive");
  if (width > limits.max_width || height > limits.max_height)
    return corrupt(what + ": image size " + std::to_string(width) + "x" + std::to_string(height) +
                   " is larger than the sensors this receiver is configured for (" +
                   std::to_string(limits.max_width) + "x" + std::to_string(limits.max_height) + ")");
  return Status::ok();
}

Status check_depth_header(const depthfuse::depth_frame_t& msg, const FrameLimits& limits,
                          const std::string& what) {
  const auto& in = msg.intrinsics;
  DF_RETURN_IF_ERROR(check_image_size(in.width, in.height, limits, what));
  const CameraIntrinsics k{in.width, in.height, in.fx, in.fy, in.cx, in.cy};
  if (auto problem = k.physical_problem()) return corrupt(what + ": " + *problem);
  if (!(msg.depth_unit_m >= limits.min_depth_unit_m && msg.depth_unit_m <= limits.max_depth_unit_m))
    return corrupt(what + ": depth_unit_m " + std::to_string(msg.depth_unit_m) +
                   " is out of range");
  if (msg.sequence < 0 || msg.sequence > std::numeric_limits<uint32_t>::max())
    return corrupt(what + ": sequence number out of range");
  if (static_cast<size_t>(msg.data_size) != msg.data.size())
    return corrupt(what + ": data_size disagrees with the data");
  return Status::ok();
}

// The frame's pose hint, or why it is left out: not a pose, or outside the workspace.
Result<Pose> checked_pose_hint(const depthfuse::depth_frame_t& msg, const FrameLimits& limits,
                               const std::string& what) {
  auto hint = pose_from_arrays(msg.hint_position_m, msg.hint_orientation_wxyz);
  if (!hint) return hint.status().with_context(what + ": pose hint");
  const double distance_m = hint->translation().norm();
  if (!(distance_m <= limits.max_pose_hint_m)) {
    char text[160];
    std::snprintf(text, sizeof text,
                  ": pose hint %.1f m from the origin, beyond the workspace (%g m, "
                  "fusion_daemon.workspace_radius_m)",
                  distance_m, limits.max_pose_hint_m);
    return invalid_argument(what + text);
  }
  return hint;
}

}  // namespace

Status decode_depth_frame(const depthfuse::depth_frame_t& msg, Frame* out,
                          const FrameLimits& limits, CodecTiming* timing, DepthFrameNotes* notes) {
  const auto& in = msg.intrinsics;
  const std::string what = "depth frame " + std::to_string(msg.sequence);
  DF_RETURN_IF_ERROR(check_depth_header(msg, limits, what));

  const size_t n = static_cast<size_t>(in.width) * in.height;
  const uint8_t* bytes = nullptr;
  thread_local std::vector<uint8_t> inflated;
  auto t0 = Clock::now();
  if (msg.encoding == depthfuse::depth_frame_t::ENCODING_RAW_UINT16) {
    if (msg.data.size() != 2 * n)
      return corrupt(what + ": " + std::to_string(msg.data.size()) + " bytes of raw depth, " +
                     std::to_string(in.width) + "x" + std::to_string(in.height) + " needs " +
                     std::to_string(2 * n));
    bytes = msg.data.data();
  } else if (msg.encoding == depthfuse::depth_frame_t::ENCODING_ZSTD_UINT16) {
    DF_RETURN_IF_ERROR(zstd_decompress(msg.data.data(), msg.data.size(), 2 * n, &inflated,
                                       what.c_str()));
    bytes = inflated.data();
    if (timing) timing->compress_ms += ms_since(t0);
  } else if (msg.encoding == depthfuse::depth_frame_t::ENCODING_ZSTD_DELTA_UINT16) {
    DF_RETURN_IF_ERROR(zstd_decompress(msg.data.data(), msg.data.size(), 2 * n, &inflated,
                                       what.c_str()));
    thread_local std::vector<uint16_t> counts;
    counts.resize(n);
    delta16_from_planes(inflated.data(), n, row_predictor(in.width), counts.data());
    inflated.resize(2 * n);
    store_le16(counts, inflated.data());
    bytes = inflated.data();
    if (timing) timing->compress_ms += ms_since(t0);
  } else {
    return corrupt(what + ": unknown depth encoding " + std::to_string(msg.encoding));
  }
  // A hint that is no pose or lies outside the workspace is left out, and the frame is taken as
  // one without a hint: its depth is good, and tracking places it (a stranger's 999 m hint must
  // not stretch the map, nor cost the frame).
  std::optional<Pose> hint;
  if (notes) notes->pose_hint_refused.clear();
  if (msg.has_pose_hint) {
    auto p = checked_pose_hint(msg, limits, what);
    if (p)
      hint = *p;
    else if (notes)
      notes->pose_hint_refused = p.status().message() + ": the frame is taken without it";
  }

  t0 = Clock::now();
  out->utime = msg.utime;
  out->sequence = static_cast<uint32_t>(msg.sequence);
  out->sensor_serial = msg.sensor_serial;
  out->intrinsics.width = in.width;
  out->intrinsics.height = in.height;
  out->intrinsics.fx = in.fx;
  out->intrinsics.fy = in.fy;
  out->intrinsics.cx = in.cx;
  out->intrinsics.cy = in.cy;
  out->depth.width = in.width;
  out->depth.height = in.height;
  out->depth.depth_m.resize(n);
  const double unit = msg.depth_unit_m;
  float* dst = out->depth.depth_m.data();
  for (size_t i = 0; i < n; ++i) {
    const uint16_t c = static_cast<uint16_t>(bytes[2 * i] | (bytes[2 * i + 1] << 8));
    dst[i] = count_to_depth(c, unit);
  }
  out->T_world_cam_hint = hint;
  if (timing) timing->convert_ms += ms_since(t0);
  return Status::ok();
}

Status encode_color_frame(const Frame& frame, const ColorEncodeOptions& options,
                          depthfuse::color_frame_t* out, CodecTiming* timing) {
  const ColorImage& c = frame.color;
  if (c.empty()) return invalid_argument("frame has no colour image");
  if (c.width <= 0 || c.height <= 0 || c.rgb.size() != static_cast<size_t>(c.width) * c.height * 3)
    return invalid_argument("colour image size does not match its dimensions");
  out->protocol_version = depthfuse::color_frame_t::PROTOCOL_VERSION;
  out->utime = frame.utime;
  out->sequence = frame.sequence;
  out->sensor_serial = frame.sensor_serial;
  out->width = c.width;
  out->height = c.height;
  auto t0 = Clock::now();
  switch (options.encoding) {
    case ColorEncoding::kRaw:
      out->encoding = depthfuse::color_frame_t::ENCODING_RAW_RGB8;
      out->data = c.rgb;
      break;
    case ColorEncoding::kZstd:
      out->encoding = depthfuse::color_frame_t::ENCODING_ZSTD_RGB8;
      DF_RETURN_IF_ERROR(zstd_compress(c.rgb.data(), c.rgb.size(), options.zstd_level, &out->data));
      break;
    case ColorEncoding::kJpeg: {
      out->encoding = depthfuse::color_frame_t::ENCODING_JPEG;
      cv::Mat rgb(c.height, c.width, CV_8UC3, const_cast<uint8_t*>(c.rgb.data()));
      cv::Mat bgr;
      cv::cvtColor(rgb, bgr, cv::COLOR_RGB2BGR);
      std::vector<uchar> jpeg;
      if (!cv::imencode(".jpg", bgr, jpeg, {cv::IMWRITE_JPEG_QUALITY, options.jpeg_quality}))
        return internal_error("JPEG encoding of the colour image failed");
      out->data.assign(jpeg.begin(), jpeg.end());
      break;
    }
  }
  out->data_size = static_cast<int32_t>(out->data.size());
  if (timing) timing->compress_ms += ms_since(t0);
  return Status::ok();
}

Status decode_color_frame(const depthfuse::color_frame_t& msg, ColorImage* out,
                          const FrameLimits& limits, CodecTiming* timing) {
  const std::string what = "colour frame " + std::to_string(msg.sequence);
  DF_RETURN_IF_ERROR(check_image_size(msg.width, msg.height, limits, what));
  if (static_cast<size_t>(msg.data_size) != msg.data.size())
    return corrupt(what + ": data_size disagrees with the data");
  const size_t bytes = static_cast<size_t>(msg.width) * msg.height * 3;
  auto t0 = Clock::now();
  if (msg.encoding == depthfuse::color_frame_t::ENCODING_RAW_RGB8) {
    if (msg.data.size() != bytes) return corrupt(what + ": raw RGB8 data has the wrong size");
    out->rgb = msg.data;
  } else if (msg.encoding == depthfuse::color_frame_t::ENCODING_ZSTD_RGB8) {
    DF_RETURN_IF_ERROR(zstd_decompress(msg.data.data(), msg.data.size(), bytes, &out->rgb,
                                       what.c_str()));
  } else if (msg.encoding == depthfuse::color_frame_t::ENCODING_JPEG) {
    const auto declared = jpeg_size(msg.data.data(), msg.data.size());
    if (!declared) return corrupt(what + ": the JPEG data has no frame header");
    if (declared->first != msg.width || declared->second != msg.height)
      return corrupt(what + ": the JPEG is " + std::to_string(declared->first) + "x" +
                     std::to_string(declared->second) + ", the message says " +
                     std::to_string(msg.width) + "x" + std::to_string(msg.height));
    cv::Mat bgr;
    try {
      bgr = cv::imdecode(cv::Mat(1, static_cast<int>(msg.data.size()), CV_8UC1,
                                 const_cast<uint8_t*>(msg.data.data())),
                         cv::IMREAD_COLOR);
    } catch (const cv::Exception&) {
      bgr.release();
    }
    if (bgr.empty()) return corrupt(what + ": the JPEG data does not decode");
    if (bgr.cols != msg.width || bgr.rows != msg.height)
      return corrupt(what + ": the JPEG is " + std::to_string(bgr.cols) + "x" +
                     std::to_string(bgr.rows) + ", the message says " + std::to_string(msg.width) +
                     "x" + std::to_string(msg.height));
    cv::Mat rgb;
    cv::cvtColor(bgr, rgb, cv::COLOR_BGR2RGB);
    out->rgb.assign(rgb.data, rgb.data + bytes);
  } else {
    return corrupt(what + ": unknown colour encoding " + std::to_string(msg.encoding));
  }
  out->width = msg.width;
  out->height = msg.height;
  if (timing) timing->compress_ms += ms_since(t0);
  return Status::ok();
}

}  // namespace depthfuse::lcm
