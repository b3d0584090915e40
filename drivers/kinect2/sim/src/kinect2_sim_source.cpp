#include "depthfuse/kinect2/kinect2_sim_source.hpp"

#include <array>
#include <condition_variable>
#include <cstdio>
#include <deque>
#include <mutex>
#include <thread>
#include <vector>

#include <libfreenect2/frame_listener.hpp>
#include <libfreenect2/libfreenect2.hpp>

#include "depthfuse/base/clock.hpp"
#include "depthfuse/kinect2/frame_assembly.hpp"
#include "depthfuse/kinect2/kinect2_source.hpp"
#include "depthfuse/kinect2/packet_decoding.hpp"
#include "depthfuse/kinect2/packet_encoder.hpp"
#include "depthfuse/kinect2/simulated_device.hpp"
#include "depthfuse/synthetic/synthetic_source.hpp"
#include "sim_camera.hpp"

namespace depthfuse::kinect2 {

namespace {

constexpr const char* kSerial = "kinect2sim";
// Packets rendered and encoded ahead of the consumer: enough to absorb a slow frame, few enough
// that the memory stays small (3 MB each).
constexpr size_t kSlots = 3;

libfreenect2::Freenect2Device::IrCameraParams ir_params(const IrCalibration& c) {
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

// The colour camera is not simulated; Registration still wants its parameters (a Kinect V2's
// typical pinhole, no depth-to-colour mapping terms).
libfreenect2::Freenect2Device::ColorCameraParams color_params() {
  libfreenect2::Freenect2Device::ColorCameraParams color{};
  color.fx = 1081.37f;
  color.fy = 1081.37f;
  color.cx = 959.5f;
  color.cy = 539.5f;
  color.shift_d = 863.0f;
  color.shift_m = 52.0f;
  return color;
}

// One packet made ahead: frame `index` of the sequence.
struct Slot {
  size_t index = 0;
  std::vector<uint8_t> packet;
  Pose T_world_cam_hint = Pose::Identity();
};

class Kinect2SimSource final : public FrameSource {
 public:
  Kinect2SimSource(synthetic::SyntheticSequence sequence, std::unique_ptr<PacketEncoder> encoder,
                   std::unique_ptr<FrameAssembly> assembly, const sim::SimCamera& camera)
      : sequence_(std::move(sequence)),
        encoder_(std::move(encoder)),
        assembly_(std::move(assembly)),
        camera_(camera) {
    for (Slot& slot : slots_) free_.push_back(&slot);
    producer_ = std::thread([this] { produce(); });
  }

  ~Kinect2SimSource() override {
    {
      std::lock_guard<std::mutex> lock(mutex_);
      stopping_ = true;
    }
    changed_.notify_all();
    producer_.join();
  }

  Result<Frame> next() override {
    for (;;) {
      if (next_index_ >= sequence_.size()) return end_of_stream();
      Slot* slot = nullptr;
      {
        std::unique_lock<std::mutex> lock(mutex_);
        changed_.wait(lock, [this] { return !ready_.empty(); });
        slot = ready_.front();
        ready_.pop_front();
      }
      // What libfreenect2's DumpPacketPipeline hands over: the packet as one Frame::Raw.
      libfreenect2::Frame raw(1, 1, slot->packet.size(), slot->packet.data());
      raw.format = libfreenect2::Frame::Raw;
      raw.sequence = ++device_sequence_;
      raw.timestamp = raw.sequence * 333;  // the device's clock: 0.1 ms units, 30 Hz
      Result<Frame> frame = assembly_->assemble(raw, nullptr);
      if (frame.is_ok()) frame->T_world_cam_hint = slot->T_world_cam_hint;
      {
        std::lock_guard<std::mutex> lock(mutex_);
        free_.push_back(slot);
        if (frame.is_ok()) {
          ++frames_;
          decode_ms_ = assembly_->times().decode_ms;
          assemble_ms_ = assembly_->times().assemble_ms;
        } else {
          ++dropped_packets_;
          last_error_ = frame.status().message();
        }
      }
      changed_.notify_all();
      ++next_index_;
      // A packet the driver refuses is dropped and counted, as from a real device.
      if (frame.is_ok()) return frame;
    }
  }

  std::string describe() const override {
    const synthetic::SyntheticConfig& c = sequence_.config();
    return std::string("kinect2sim:") + synthetic::to_string(c.scene) + " (" +
           std::to_string(sequence_.size()) + " frames, seed " + std::to_string(c.seed) +
           ", simulated Kinect V2 packets through the depthfuse decoder)";
  }

  std::optional<double> nominal_rate_hz() const override { return sequence_.config().rate_hz; }
  std::optional<size_t> frame_count() const override { return sequence_.size(); }

  Status rewind() override {
    {
      std::lock_guard<std::mutex> lock(mutex_);
      ++generation_;
      for (Slot* slot : ready_) free_.push_back(slot);
      ready_.clear();
      produce_index_ = 0;
    }
    changed_.notify_all();
    next_index_ = 0;
    return Status::ok();
  }

  std::optional<DeviceStatus> device_status() const override {
    std::lock_guard<std::mutex> lock(mutex_);
    DeviceStatus status;
    status.reading = DeviceStatus::Reading::kStreaming;
    const double frames = static_cast<double>(std::max<uint64_t>(frames_, 1));
    const double made = static_cast<double>(std::max<uint64_t>(packets_made_, 1));
    char line[256];
    std::snprintf(line, sizeof line,
                  "streaming: simulated Kinect V2 (%llu frames, %llu dropped packets; per frame "
                  "%.1f ms decoding, %.1f ms in the driver, %.1f ms rendering, %.1f ms encoding)",
                  static_cast<unsigned long long>(frames_),
                  static_cast<unsigned long long>(dropped_packets_), decode_ms_ / frames,
                  assemble_ms_ / frames, render_ms_ / made, encode_ms_ / made);
    status.summary = line;
    if (!last_error_.empty()) status.summary += "; last bad packet: " + last_error_;
    status.counters = {{"kinect2sim_frames", static_cast<double>(frames_)},
                       {"kinect2sim_dropped_packets", static_cast<double>(dropped_packets_)},
                       {"kinect2sim_decode_ms_mean", decode_ms_ / frames},
                       {"kinect2sim_driver_ms_mean", assemble_ms_ / frames},
                       {"kinect2sim_render_ms_mean", render_ms_ / made},
                       {"kinect2sim_encode_ms_mean", encode_ms_ / made}};
    return status;
  }

 private:
  // The producer thread: renders and encodes the frames in order into free slots.
  void produce() {
    Frame rendered;
    DepthImage depth;
    IrImage ir;
    std::unique_lock<std::mutex> lock(mutex_);
    for (;;) {
      changed_.wait(lock, [this] {
        return stopping_ || (!free_.empty() && produce_index_ < sequence_.size());
      });
      if (stopping_) return;
      Slot* slot = free_.front();
      free_.pop_front();
      const size_t index = produce_index_++;
      const uint64_t generation = generation_;
      lock.unlock();

      const int64_t start_ns = steady_ns();
      sequence_.render_into(index, /*with_noise=*/true, &rendered, /*with_color=*/false);
      camera_.measure(rendered.depth, &depth, &ir);
      const int64_t rendered_ns = steady_ns();
      // The images are the right size by construction: encode() cannot refuse them.
      (void)encoder_->encode(depth, ir, &slot->packet);
      const int64_t encoded_ns = steady_ns();
      slot->index = index;
      slot->T_world_cam_hint = *rendered.T_world_cam_hint;

      lock.lock();
      render_ms_ += (rendered_ns - start_ns) * 1e-6;
      encode_ms_ += (encoded_ns - rendered_ns) * 1e-6;
      ++packets_made_;
      if (generation == generation_)
        ready_.push_back(slot);
      else
        free_.push_back(slot);  // made before a rewind
      changed_.notify_all();
    }
  }

  const synthetic::SyntheticSequence sequence_;
  const std::unique_ptr<PacketEncoder> encoder_;
  const std::unique_ptr<FrameAssembly> assembly_;  // the consumer's (next()) only
  const sim::SimCamera camera_;
  size_t next_index_ = 0;         // the consumer's
  uint32_t device_sequence_ = 0;  // the consumer's: the device's frame counter never restarts

  mutable std::mutex mutex_;
  std::condition_variable changed_;
  std::array<Slot, kSlots> slots_;
  std::deque<Slot*> free_, ready_;  // ready_ in frame order
  size_t produce_index_ = 0;
  uint64_t generation_ = 0;  // increases at every rewind
  bool stopping_ = false;
  uint64_t frames_ = 0, dropped_packets_ = 0, packets_made_ = 0;
  double decode_ms_ = 0, assemble_ms_ = 0, render_ms_ = 0, encode_ms_ = 0;
  std::string last_error_;
  std::thread producer_;  // last: starts after everything it uses
};

}  // namespace

Result<std::unique_ptr<FrameSource>> open_kinect2sim_source(const std::string& arg,
                                                            const AppConfig& config) {
  auto options = kinect2_options_from_config("", config);
  if (!options.is_ok()) return options.status().with_context("kinect2sim");
  const IrCalibration calibration = simulated_ir_calibration();
  const P0Tables p0 = simulated_p0_tables();
  const sim::SimCamera camera(calibration);

  synthetic::SyntheticConfig base;
  base.intrinsics = camera.pinhole();
  base.noise.enabled = false;
  // The renderer keeps everything the sensor could see; the decoder applies the configured range.
  base.min_depth_m = 0.05;
  base.max_depth_m = 17.0;
  auto parsed = synthetic::parse_synthetic_spec(arg, base);
  if (!parsed.is_ok()) return parsed.status().with_context("kinect2sim");
  auto sequence = synthetic::SyntheticSequence::create(parsed.value());
  if (!sequence.is_ok()) return sequence.status().with_context("kinect2sim");

  auto encoder = PacketEncoder::create(p0, calibration);
  if (!encoder.is_ok()) return encoder.status().with_context("kinect2sim");
  DepthDecoderOptions decoder;
  decoder.min_depth_m = static_cast<float>(options->min_depth_m);
  decoder.max_depth_m = static_cast<float>(options->max_depth_m);
  decoder.bilateral_filter = options->bilateral_filter;
  decoder.edge_aware_filter = options->edge_aware_filter;
  decoder.threads = options->decoder_threads;
  const std::vector<uint8_t> p0_bytes = p0_response(p0);
  auto decoding = PacketDecoding::create(p0_bytes.data(), p0_bytes.size(), ir_params(calibration),
                                         decoder);
  if (!decoding.is_ok()) return decoding.status().with_context("kinect2sim");
  auto assembly = FrameAssembly::create(ir_params(calibration), color_params(), kSerial,
                                        std::move(decoding).value());
  if (!assembly.is_ok()) return assembly.status().with_context("kinect2sim");
  return std::unique_ptr<FrameSource>(
      new Kinect2SimSource(std::move(sequence).value(), std::move(encoder).value(),
                           std::move(assembly).value(), camera));
}

}  // namespace depthfuse::kinect2
