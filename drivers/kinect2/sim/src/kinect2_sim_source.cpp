#include "depthfuse/kinect2/kinect2_sim_source.hpp"

#include <algorithm>
#include <array>
#include <cstdlib>
#include <condition_variable>
#include <cstdio>
#include <deque>
#include <mutex>
#include <optional>
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

// A frame's packet with the pose it was rendered from.
struct Packet {
  std::vector<uint8_t> bytes;
  std::optional<Pose> T_world_cam_hint;  // none when the spec says hints=0
};

// One packet made ahead: its own, or one of the cache.
struct Slot {
  Packet own;
  Packet* packet = nullptr;
};

// Takes kinect2sim's own option, cache_mb=N, out of the spec's query (the rest are the synthetic
// source's); 0 when absent.
Result<size_t> take_cache_mb(std::string* arg) {
  const size_t q = arg->find('?');
  if (q == std::string::npos) return size_t{0};
  size_t cache_mb = 0;
  std::string kept;
  size_t start = q + 1;
  while (start <= arg->size()) {
    const size_t amp = std::min(arg->find('&', start), arg->size());
    const std::string item = arg->substr(start, amp - start);
    start = amp + 1;
    if (item.rfind("cache_mb=", 0) != 0) {
      if (!item.empty()) kept += (kept.empty() ? "" : "&") + item;
      continue;
    }
    const std::string value = item.substr(9);
    char* end = nullptr;
    const unsigned long long mb = std::strtoull(value.c_str(), &end, 10);
    if (value.empty() || *end != '\0' || value[0] == '-' || mb > (1ull << 20))
      return invalid_argument("kinect2sim '" + *arg + "': bad value '" + value +
                              "' for 'cache_mb' (expected an integer from 0 to 1048576)");
    cache_mb = static_cast<size_t>(mb);
  }
  *arg = arg->substr(0, q) + (kept.empty() ? "" : "?" + kept);
  return cache_mb;
}

class Kinect2SimSource final : public FrameSource {
 public:
  Kinect2SimSource(synthetic::SyntheticSequence sequence, std::unique_ptr<PacketEncoder> encoder,
                   std::unique_ptr<FrameAssembly> assembly, const sim::SimCamera& camera,
                   size_t cache_bytes)
      : sequence_(std::move(sequence)),
        encoder_(std::move(encoder)),
        assembly_(std::move(assembly)),
        camera_(camera),
        cache_(sequence_.size()),
        cache_capacity_(cache_bytes / kRawPacketBytes),
        next_index_(first_frame()),
        produce_index_(first_frame()) {
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
      std::vector<uint8_t>& bytes = slot->packet->bytes;  // only read from here on
      libfreenect2::Frame raw(1, 1, bytes.size(), bytes.data());
      raw.format = libfreenect2::Frame::Raw;
      raw.sequence = ++device_sequence_;
      raw.timestamp = raw.sequence * 333;  // the device's clock: 0.1 ms units, 30 Hz
      Result<Frame> frame = assembly_->assemble(raw, nullptr);
      if (frame.is_ok()) frame->T_world_cam_hint = slot->packet->T_world_cam_hint;
      {
        std::lock_guard<std::mutex> lock(mutex_);
        free_.push_back(slot);
        stats_ = assembly_->stats();
        if (!frame.is_ok()) last_error_ = frame.status().message();
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
           (c.first_frame > 0 ? ", from frame " + std::to_string(c.first_frame) : "") +
           ", simulated Kinect V2 packets through the depthfuse decoder)";
  }

  std::optional<double> nominal_rate_hz() const override { return sequence_.config().rate_hz; }
  std::optional<size_t> frame_count() const override { return sequence_.size() - first_frame(); }

  Status rewind() override {
    {
      std::lock_guard<std::mutex> lock(mutex_);
      ++generation_;
      for (Slot* slot : ready_) free_.push_back(slot);
      ready_.clear();
      produce_index_ = first_frame();
    }
    changed_.notify_all();
    next_index_ = first_frame();
    return Status::ok();
  }

  std::optional<DeviceStatus> device_status() const override {
    std::lock_guard<std::mutex> lock(mutex_);
    DeviceStatus status;
    status.reading = DeviceStatus::Reading::kStreaming;
    const double frames = static_cast<double>(std::max<uint64_t>(stats_.frames, 1));
    const double made = static_cast<double>(std::max<uint64_t>(packets_made_, 1));
    char line[256];
    std::snprintf(line, sizeof line,
                  "streaming: simulated Kinect V2 (%llu frames, %llu dropped packets; CPU per "
                  "frame %.1f ms decoding, %.1f ms in the driver, %.1f ms rendering, %.1f ms "
                  "encoding; %llu packets cached)",
                  static_cast<unsigned long long>(stats_.frames),
                  static_cast<unsigned long long>(stats_.dropped), stats_.decode_ms / frames,
                  stats_.assemble_ms / frames, render_ms_ / made, encode_ms_ / made,
                  static_cast<unsigned long long>(cached_));
    status.summary = line;
    if (!last_error_.empty()) status.summary += "; last bad packet: " + last_error_;
    status.counters = {{"kinect2sim_frames", static_cast<double>(stats_.frames)},
                       {"kinect2sim_dropped_packets", static_cast<double>(stats_.dropped)},
                       {"kinect2sim_decode_ms_mean", stats_.decode_ms / frames},
                       {"kinect2sim_driver_ms_mean", stats_.assemble_ms / frames},
                       {"kinect2sim_render_ms_mean", render_ms_ / made},
                       {"kinect2sim_encode_ms_mean", encode_ms_ / made},
                       {"kinect2sim_cached_packets", static_cast<double>(cached_)}};
    return status;
  }

 private:
  // The producer thread: renders and encodes the frames in order into free slots, or takes them
  // from the cache. Only this thread touches the cache; its packets are never changed or freed
  // while the source lives, so a slot may point into it.
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

      bool made = false;
      double render_ms = 0, encode_ms = 0;
      if (cache_[index]) {
        slot->packet = cache_[index].get();
      } else {
        Packet* packet = &slot->own;
        if (cached_count_ < cache_capacity_) {
          cache_[index] = std::make_unique<Packet>();
          packet = cache_[index].get();
          ++cached_count_;
        }
        const int64_t start_ns = thread_cpu_ns();
        sequence_.render_into(index, /*with_noise=*/true, &rendered, /*with_color=*/false);
        camera_.measure(rendered.depth, &depth, &ir);
        const int64_t rendered_ns = thread_cpu_ns();
        // The images are the right size by construction: encode() cannot refuse them.
        (void)encoder_->encode(depth, ir, &packet->bytes);
        packet->T_world_cam_hint = rendered.T_world_cam_hint;
        render_ms = (rendered_ns - start_ns) * 1e-6;
        encode_ms = (thread_cpu_ns() - rendered_ns) * 1e-6;
        slot->packet = packet;
        made = true;
      }

      lock.lock();
      if (made) {
        render_ms_ += render_ms;
        encode_ms_ += encode_ms;
        ++packets_made_;
      }
      cached_ = cached_count_;
      if (generation == generation_)
        ready_.push_back(slot);
      else
        free_.push_back(slot);  // made before a rewind
      changed_.notify_all();
    }
  }

  // The spec's first=F: the stream starts at frame F of the walk, and a rewind goes back there.
  size_t first_frame() const { return static_cast<size_t>(sequence_.config().first_frame); }

  const synthetic::SyntheticSequence sequence_;
  const std::unique_ptr<PacketEncoder> encoder_;
  const std::unique_ptr<FrameAssembly> assembly_;  // the consumer's (next()) only
  const sim::SimCamera camera_;
  // The producer's: packets kept by frame index, at most cache_capacity_ of them.
  std::vector<std::unique_ptr<Packet>> cache_;
  const size_t cache_capacity_;
  size_t cached_count_ = 0;
  size_t next_index_ = 0;         // the consumer's
  uint32_t device_sequence_ = 0;  // the consumer's: the device's frame counter never restarts

  mutable std::mutex mutex_;
  std::condition_variable changed_;
  std::array<Slot, kSlots> slots_;
  std::deque<Slot*> free_, ready_;  // ready_ in frame order
  size_t produce_index_ = 0;
  uint64_t generation_ = 0;  // increases at every rewind
  bool stopping_ = false;
  AssemblyStats stats_;  // a copy of the assembly's, for device_status() on another thread
  uint64_t packets_made_ = 0, cached_ = 0;
  double render_ms_ = 0, encode_ms_ = 0;
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

  std::string spec = arg;
  auto cache_mb = take_cache_mb(&spec);
  if (!cache_mb.is_ok()) return cache_mb.status();
  synthetic::SyntheticConfig base;
  base.intrinsics = camera.pinhole();
  base.noise.enabled = false;
  // The renderer keeps everything the sensor could see; the decoder applies the configured range.
  base.min_depth_m = 0.05;
  base.max_depth_m = 17.0;
  auto parsed = synthetic::parse_synthetic_spec(spec, base);
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
  auto decoding = PacketDecoding::create(p0_bytes.data(), p0_bytes.size(), ir_camera_params(calibration),
                                         decoder);
  if (!decoding.is_ok()) return decoding.status().with_context("kinect2sim");
  auto assembly = FrameAssembly::create(ir_camera_params(calibration), color_params(), kSerial,
                                        std::move(decoding).value());
  if (!assembly.is_ok()) return assembly.status().with_context("kinect2sim");
  return std::unique_ptr<FrameSource>(
      new Kinect2SimSource(std::move(sequence).value(), std::move(encoder).value(),
                           std::move(assembly).value(), camera,
                           cache_mb.value() * size_t{1024} * 1024));
}

}  // namespace depthfuse::kinect2
