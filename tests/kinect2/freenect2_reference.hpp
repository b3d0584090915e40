// libfreenect2's own CPU depth decoder (CpuDepthPacketProcessor), driven directly with a packet:
// the reference the agreement test and the benchmark compare depthfuse's decoder against. It is
// reached through CpuPacketPipeline::getDepthPacketProcessor() with libfreenect2's internal header
// (not installed; CMake takes it from the libfreenect2 source, DEPTHFUSE_LIBFREENECT2_SOURCE).
#pragma once

#include <memory>
#include <vector>

#include "depthfuse/kinect2/raw_depth.hpp"

namespace depthfuse::kinect2::test {

class Freenect2CpuDecoder {
 public:
  // Loads the P0 tables (as the device's command response), the x/z tables of `calibration` and
  // the code table, as libfreenect2 does when a device opens.
  Freenect2CpuDecoder(const P0Tables& p0, const IrCalibration& calibration, float min_depth_m,
                      float max_depth_m, bool bilateral_filter, bool edge_aware_filter);
  ~Freenect2CpuDecoder();

  // One packet to depth in millimetres and IR, 512x424 as libfreenect2 delivers them. The packet
  // is passed mutable, as libfreenect2 takes it (it does not write to it).
  void decode(std::vector<uint8_t>* packet, uint32_t sequence, std::vector<float>* depth_mm,
              std::vector<float>* ir);

  class Impl;

 private:
  std::unique_ptr<Impl> impl_;
};

}  // namespace depthfuse::kinect2::test
