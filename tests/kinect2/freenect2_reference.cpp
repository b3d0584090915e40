#include "freenect2_reference.hpp"

#include <cstring>

#include <libfreenect2/depth_packet_processor.h>  // internal header of libfreenect2
#include <libfreenect2/frame_listener.hpp>
#include <libfreenect2/logger.h>
#include <libfreenect2/packet_pipeline.h>

#include "decoder_tables.hpp"

namespace depthfuse::kinect2::test {

namespace {

// Copies the frames out and leaves them to the processor, which reuses them.
class CopyingListener : public libfreenect2::FrameListener {
 public:
  bool onNewFrame(libfreenect2::Frame::Type type, libfreenect2::Frame* frame) override {
    std::vector<float>* target = type == libfreenect2::Frame::Depth ? depth_mm : ir;
    if (target != nullptr) {
      target->resize(frame->width * frame->height);
      std::memcpy(target->data(), frame->data, target->size() * sizeof(float));
    }
    return false;
  }
  std::vector<float>* depth_mm = nullptr;
  std::vector<float>* ir = nullptr;
};

}  // namespace

class Freenect2CpuDecoder::Impl {
 public:
  libfreenect2::CpuPacketPipeline pipeline;
  libfreenect2::DepthPacketProcessor* processor = pipeline.getDepthPacketProcessor();
  CopyingListener listener;
};

Freenect2CpuDecoder::Freenect2CpuDecoder(const P0Tables& p0, const IrCalibration& calibration,
                                         float min_depth_m, float max_depth_m,
                                         bool bilateral_filter, bool edge_aware_filter)
    : impl_(std::make_unique<Impl>()) {
  libfreenect2::setGlobalLogger(nullptr);  // it logs every frame's timing
  libfreenect2::DepthPacketProcessor& processor = *impl_->processor;
  processor.setFrameListener(&impl_->listener);
  libfreenect2::DepthPacketProcessor::Config config;
  config.MinDepth = min_depth_m;
  config.MaxDepth = max_depth_m;
  config.EnableBilateralFilter = bilateral_filter;
  config.EnableEdgeAwareFilter = edge_aware_filter;
  processor.setConfiguration(config);
  std::vector<uint8_t> response = p0_response(p0);
  processor.loadP0TablesFromCommandResponse(response.data(), response.size());
  // libfreenect2 computes these in its (unexported) IrCameraTables; ours follow the same
  // formulas and are fed to both decoders, so the comparison is of the decoding itself.
  const RayTables rays = make_ray_tables(calibration);
  processor.loadXZTables(rays.x_scaled.data(), rays.z_mm_per_phase.data());
  processor.loadLookupTable(code_to_correlation().data());
}

Freenect2CpuDecoder::~Freenect2CpuDecoder() = default;

void Freenect2CpuDecoder::decode(std::vector<uint8_t>* packet, uint32_t sequence,
                                 std::vector<float>* depth_mm, std::vector<float>* ir) {
  impl_->listener.depth_mm = depth_mm;
  impl_->listener.ir = ir;
  libfreenect2::DepthPacket p{};
  p.sequence = sequence;
  p.buffer = packet->data();
  p.buffer_length = packet->size();
  impl_->processor->process(p);
}

}  // namespace depthfuse::kinect2::test
