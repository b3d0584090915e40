// Frame <-> depth_frame_t / color_frame_t, and poses <-> pose_t arrays. Depth goes over the wire as
// uint16 counts of depth_unit_m (lossless for depth quantised to that unit: Kinect V2 and TUM data),
// raw or zstd-compressed; colour raw, zstd or JPEG.
#pragma once

#include <cstdint>
#include <string>

#include "depthfuse/color_frame_t.hpp"
#include "depthfuse/depth_frame_t.hpp"
#include "depthfuse/pose_t.hpp"
#include "depthfuse/status.hpp"
#include "depthfuse/types.hpp"

namespace depthfuse::lcm {

struct DepthEncodeOptions {
  bool compress = true;         // zstd (ENCODING_ZSTD_DELTA_UINT16 with predict_rows)
  bool predict_rows = true;     // row delta + zigzag + byte planes before zstd: ~2x smaller
  int zstd_level = 1;           // 1 is fastest; higher levels cost CPU on the capture board
  double depth_unit_m = 0.001;  // one count; 65535 counts = 65.5 m at 1 mm
};

enum class ColorEncoding { kRaw, kZstd, kJpeg };
struct ColorEncodeOptions {
  ColorEncoding encoding = ColorEncoding::kZstd;
  int zstd_level = 1;
  int jpeg_quality = 90;        // 0..100, only for kJpeg (lossy)
};

// Where the time of one encode/decode went, for the benchmark (milliseconds).
struct CodecTiming {
  double convert_ms = 0;   // float metres <-> uint16 counts
  double compress_ms = 0;  // zstd or JPEG
  double serialize_ms = 0; // filled by callers that encode the LCM message themselves
};

// What a receiver accepts of a frame. Checked on the message's header before anything is
// decompressed or allocated, so that a few bytes claiming a huge image cost nothing: the image no
// larger than the sensors the receiver was configured for, intrinsics of a real camera. A frame
// outside them is refused with a message naming the field. A pose hint outside the scanned site
// (or no pose at all) costs only the hint (DepthFrameNotes).
struct FrameLimits {
  int max_width = 640;    // px; Kinect V2 depth is 512 x 424, TUM's Kinect v1 640 x 480
  int max_height = 480;
  // The intrinsics must be a camera's: CameraIntrinsics::physical_problem().
  double max_pose_hint_m = 100.0;  // distance of a pose hint from the origin (workspace_radius_m)
  double min_depth_unit_m = 1e-6;         // one count of depth: 1 um ... 1 m
  double max_depth_unit_m = 1.0;
};

// What decode_depth_frame left out of a frame it took.
struct DepthFrameNotes {
  // Why the frame's pose hint was left out (beyond FrameLimits::max_pose_hint_m, not finite, not
  // a rotation); empty when it was kept or there was none. The frame is then one without a hint.
  std::string pose_hint_refused;
};

// Depth in metres -> counts: round(d / unit); depth <= 0, NaN or beyond 65535 counts becomes 0.
// `publish_utime` is stamped by the caller just before publishing.
Status encode_depth_frame(const Frame& frame, const DepthEncodeOptions& options,
                          depthfuse::depth_frame_t* out, CodecTiming* timing = nullptr);

// Checks the message against `limits` first, then its encoding and decompressed length, and fills
// the frame's utime, sequence, serial, intrinsics, depth and pose hint (left out, and said in
// *notes, when it is not a pose within the limits). Colour is left untouched.
Status decode_depth_frame(const depthfuse::depth_frame_t& msg, Frame* out,
                          const FrameLimits& limits = {}, CodecTiming* timing = nullptr,
                          DepthFrameNotes* notes = nullptr);

// Fails on a frame without colour or whose colour size differs from its depth size.
Status encode_color_frame(const Frame& frame, const ColorEncodeOptions& options,
                          depthfuse::color_frame_t* out, CodecTiming* timing = nullptr);
// Colour is registered to depth pixel for pixel: its size is held to the same limits.
Status decode_color_frame(const depthfuse::color_frame_t& msg, ColorImage* out,
                          const FrameLimits& limits = {}, CodecTiming* timing = nullptr);

void pose_to_arrays(const Pose& T, double position_m[3], double orientation_wxyz[4]);
// Normalises the quaternion; fails when it is not finite or has (near) zero norm.
Result<Pose> pose_from_arrays(const double position_m[3], const double orientation_wxyz[4]);

}  // namespace depthfuse::lcm
