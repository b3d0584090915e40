// depthfuse's Kinect V2 depth decoder: one raw depth packet (raw_depth.hpp) to a depth image in
// metres and an IR image, the same computation as libfreenect2's CPU depth decoder (same phase
// unwrapping, bilateral and edge-aware filters, same invalid pixels) without its cost: everything
// per pixel and per device is a table computed once, rows are processed as structure-of-arrays
// loops the compiler vectorises, nothing is allocated per frame, and the work can be split over
// two threads.
//
// Output images are 512x424 in libfreenect2's orientation and still distorted (raw IR optics):
// the driver undistorts them as it does libfreenect2's. Depth is in metres, 0 where there is no
// measurement; IR is the amplitude, 0 to 65535.
#pragma once

#include <memory>
#include <vector>

#include "depthfuse/kinect2/raw_depth.hpp"
#include "depthfuse/status.hpp"
#include "depthfuse/types.hpp"

namespace depthfuse::kinect2 {

struct DepthDecoderOptions {
  float min_depth_m = 0.5f;       // with the edge-aware filter on, nearer is "no measurement"
  float max_depth_m = 4.5f;       // with the edge-aware filter on, farther is "no measurement"
  bool bilateral_filter = true;   // libfreenect2 Config::EnableBilateralFilter
  bool edge_aware_filter = true;  // libfreenect2 Config::EnableEdgeAwareFilter
  int threads = 1;                // 1 or 2
};
Status check_decoder_options(const DepthDecoderOptions& options);

// IR amplitude, row-major, same size as the depth image.
struct IrImage {
  int width = 0;
  int height = 0;
  std::vector<float> amplitude;
};

class DepthDecoder {
 public:
  // Builds the per-device tables (a few tens of milliseconds). kInvalidArgument for bad options,
  // missing or malformed P0 tables, or a calibration that is not finite.
  static Result<std::unique_ptr<DepthDecoder>> create(const P0Tables& p0,
                                                      const IrCalibration& calibration,
                                                      const DepthDecoderOptions& options);
  ~DepthDecoder();
  DepthDecoder(const DepthDecoder&) = delete;
  DepthDecoder& operator=(const DepthDecoder&) = delete;

  // Decodes one packet into `depth` and, unless it is null, `ir` (resized on first use, then
  // reused). kInvalidArgument
  // for a packet of the wrong size or without data, and for a sequence number not after the
  // previous packet's; the outputs are then left as they were.
  Status decode(const RawDepthPacket& packet, DepthImage* depth, IrImage* ir);
  // The same with depth in millimetres (libfreenect2's unit) into `depth_mm`, 512x424 floats:
  // what the driver hands to libfreenect2's registration, without a round trip through metres.
  Status decode_millimetres(const RawDepthPacket& packet, float* depth_mm, IrImage* ir);

  // After the device restarted its frame counter (reopen): any next sequence number is accepted.
  void restart_sequence();

  class Impl;

 private:
  explicit DepthDecoder(std::unique_ptr<Impl> impl);
  std::unique_ptr<Impl> impl_;
};

}  // namespace depthfuse::kinect2
