// The forward model of the Kinect V2's depth camera: from the depth and IR images the decoder
// should see (depth_decoder.hpp: libfreenect2's orientation, distorted, metres and amplitude) to
// the raw packet the device would send, for a device with the given P0 tables and calibration.
// For tests and the simulated sensor: the decoder then runs on real packets without hardware.
//
// Each pixel's unwrapped phase is solved from its depth (inverting the decoder's phase-to-depth
// mapping), split into the three frequencies' wrapped phases, and each phase-stepped correlation
// is the amplitude times the cosine of (P0 + phase step + phase), quantised to the nearest 11-bit
// code. An IR value of 65535 or more gives a saturated pixel; depth 0 gives a pixel without
// signal. The packet's sub-image 9 is left zero (the decoder does not read it).
#pragma once

#include <memory>
#include <vector>

#include "depthfuse/kinect2/depth_decoder.hpp"
#include "depthfuse/kinect2/raw_depth.hpp"
#include "depthfuse/status.hpp"
#include "depthfuse/types.hpp"

namespace depthfuse::kinect2 {

class PacketEncoder {
 public:
  // kInvalidArgument for missing P0 tables or a calibration that is not finite.
  static Result<std::unique_ptr<PacketEncoder>> create(const P0Tables& p0,
                                                       const IrCalibration& calibration);
  ~PacketEncoder();
  PacketEncoder(const PacketEncoder&) = delete;
  PacketEncoder& operator=(const PacketEncoder&) = delete;

  // `packet` is resized to kRawPacketBytes (storage reused). kInvalidArgument unless both images
  // are 512x424. Depths beyond the unambiguous range (about 18 m) are encoded as no signal.
  Status encode(const DepthImage& depth, const IrImage& ir, std::vector<uint8_t>* packet) const;

  class Impl;

 private:
  explicit PacketEncoder(std::unique_ptr<Impl> impl);
  std::unique_ptr<Impl> impl_;
};

}  // namespace depthfuse::kinect2
