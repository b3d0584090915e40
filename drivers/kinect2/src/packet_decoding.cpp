#include "depthfuse/kinect2/packet_decoding.hpp"

#include <cstdint>
#include <string>

namespace depthfuse::kinect2 {

IrCalibration ir_calibration(const libfreenect2::Freenect2Device::IrCameraParams& ir) {
  IrCalibration c;
  c.fx = ir.fx;
  c.fy = ir.fy;
  c.cx = ir.cx;
  c.cy = ir.cy;
  c.k1 = ir.k1;
  c.k2 = ir.k2;
  c.k3 = ir.k3;
  c.p1 = ir.p1;
  c.p2 = ir.p2;
  return c;
}

libfreenect2::Freenect2Device::IrCameraParams ir_camera_params(const IrCalibration& c) {
  libfreenect2::Freenect2Device::IrCameraParams ir{};
  ir.fx = c.fx;
  ir.fy = c.fy;
  ir.cx = c.cx;
  ir.cy = c.cy;
  ir.k1 = c.k1;
  ir.k2 = c.k2;
  ir.k3 = c.k3;
  ir.p1 = c.p1;
  ir.p2 = c.p2;
  return ir;
}

Result<std::unique_ptr<PacketDecoding>> PacketDecoding::create(
    const uint8_t* p0_response, size_t p0_size,
    const libfreenect2::Freenect2Device::IrCameraParams& ir, const DepthDecoderOptions& options) {
  auto p0 = parse_p0_response(p0_response, p0_size);
  if (!p0.is_ok()) return p0.status().with_context("depthfuse depth pipeline");
  auto decoder = DepthDecoder::create(p0.value(), ir_calibration(ir), options);
  if (!decoder.is_ok()) return decoder.status().with_context("depthfuse depth pipeline");
  return std::unique_ptr<PacketDecoding>(new PacketDecoding(std::move(decoder).value()));
}

Status PacketDecoding::decode(const libfreenect2::Frame& raw, libfreenect2::Frame* depth_mm) {
  if (raw.format != libfreenect2::Frame::Raw)
    return invalid_argument("depthfuse depth pipeline: expected a raw depth packet, got frame format " +
                            std::to_string(static_cast<int>(raw.format)));
  if (depth_mm->width != kRawWidth || depth_mm->height != kRawHeight ||
      depth_mm->bytes_per_pixel != sizeof(float))
    return invalid_argument("depthfuse depth pipeline: the output frame must be 512x424x4");
  if (reinterpret_cast<uintptr_t>(depth_mm->data) % alignof(float) != 0)
    return invalid_argument("depthfuse depth pipeline: the output frame's data is not aligned for "
                            "floats");
  const size_t size = raw.width * raw.height * raw.bytes_per_pixel;
  // The capture publishes depth only: the decoder skips the IR image. libfreenect2's frames hold
  // floats in 64-byte aligned storage (its own pipelines write them as float arrays too).
  DF_RETURN_IF_ERROR(decoder_->decode_millimetres(
      RawDepthPacket{raw.sequence, raw.timestamp, raw.data, size},
      reinterpret_cast<float*>(depth_mm->data), nullptr));
  depth_mm->format = libfreenect2::Frame::Float;
  depth_mm->sequence = raw.sequence;
  depth_mm->timestamp = raw.timestamp;
  return Status::ok();
}

}  // namespace depthfuse::kinect2
