#include "depthfuse/kinect2/kinect2_source.hpp"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <mutex>

#include <libfreenect2/frame_listener_impl.h>
#include <libfreenect2/libfreenect2.hpp>

#include "depthfuse/kinect2/conversion.hpp"
#include "depthfuse/kinect2/frame_assembly.hpp"
#include "depthfuse/kinect2/packet_decoding.hpp"
#include "depthfuse/kinect2/packet_pipeline.hpp"
#include "depthfuse/kinect2/usb_hotplug.hpp"
#include "depthfuse/kinect2/usb_reset.hpp"
#include "freenect2_log.hpp"

namespace depthfuse::kinect2 {

namespace {

using kinect2::DeviceLink;
using kinect2::LinkAction;
using Clock = std::chrono::steady_clock;

Clock::duration seconds(double s) {
  return std::chrono::duration_cast<Clock::duration>(std::chrono::duration<double>(s));
}

std::string joined(const std::vector<std::string>& items) {
  std::string text;
  for (const auto& item : items) text += (text.empty() ? "" : ", ") + item;
  return text;
}

// "; libfreenect2: <its last error>" or "".
std::string freenect2_reason() {
  const std::string error = kinect2::last_freenect2_error();
  return error.empty() ? std::string() : "; libfreenect2: " + error;
}

Status check_positive(double value, const char* key) {
  if (!(std::isfinite(value) && value > 0.0))
    return invalid_argument(std::string(key) + " must be a finite number > 0, got " +
                            std::to_string(value));
  return Status::ok();
}

Status validate(const Kinect2Options& o) {
  DF_RETURN_IF_ERROR(kinect2::check_pipeline(o.pipeline));
  if (!(std::isfinite(o.min_depth_m) && o.min_depth_m >= 0.0))
    return invalid_argument("capture.kinect2_min_depth_m must be a finite number >= 0, got " +
                            std::to_string(o.min_depth_m));
  if (!(std::isfinite(o.max_depth_m) && o.max_depth_m > o.min_depth_m))
    return invalid_argument("capture.kinect2_max_depth_m must be finite and greater than "
                            "capture.kinect2_min_depth_m (" +
                            std::to_string(o.min_depth_m) + "), got " +
                            std::to_string(o.max_depth_m));
  if (o.decoder_threads != 1 && o.decoder_threads != 2)
    return invalid_argument("capture.kinect2_decoder_threads must be 1 or 2, got " +
                            std::to_string(o.decoder_threads));
  DF_RETURN_IF_ERROR(check_positive(o.stall_timeout_s, "capture.kinect2_stall_timeout_s"));
  DF_RETURN_IF_ERROR(check_positive(o.first_frame_timeout_s, "kinect2 first_frame_timeout_s"));
  DF_RETURN_IF_ERROR(check_positive(o.open_retry_interval_s, "kinect2 open_retry_interval_s"));
  DF_RETURN_IF_ERROR(check_positive(o.max_wait_s, "kinect2 max_wait_s"));
  for (const DeviceCalibration& calibration : o.calibrations)
    DF_RETURN_IF_ERROR(kinect2::check_device_calibration(calibration));
  return Status::ok();
}

class Kinect2SourceImpl final : public Kinect2Source {
 public:
  Kinect2SourceImpl(Kinect2Options options, std::unique_ptr<kinect2::UsbHotplugMonitor> monitor)
      : options_(std::move(options)),
        monitor_(std::move(monitor)),
        link_(link_config(options_)) {
    publish_status();
  }

  ~Kinect2SourceImpl() override {
    close_device();
    context_.reset();
  }

  Result<Frame> next() override {
    const Clock::time_point deadline = Clock::now() + seconds(options_.max_wait_s);
    for (;;) {
      const uint64_t generation = monitor_->presence().generation();
      step(generation);

      if (device_ != nullptr && link_.state() == Kinect2State::kConnected) {
        const Clock::time_point now = Clock::now();
        // Wake at least every 100 ms to notice an unplug that the frame wait would not see.
        const Clock::time_point until =
            std::min({deadline, link_.next_deadline(), now + std::chrono::milliseconds(100)});
        const auto wait_ms = std::max<int64_t>(
            1, std::chrono::duration_cast<std::chrono::milliseconds>(until - now).count());
        libfreenect2::FrameMap frames;
        if (listener_->waitForNewFrame(frames, static_cast<int>(wait_ms))) {
          Result<Frame> frame = convert(frames);
          listener_->release(frames);
          if (frame.is_ok()) {
            run(link_.on_frame(Clock::now()));
            std::lock_guard<std::mutex> lock(status_mutex_);
            status_.last_frame_utime = frame->utime;
            ++delivered_;
            fill_status_locked();
            return frame;
          }
          // A malformed frame from the device: skip it, the stall timer still runs.
          last_frame_error_ = frame.status().message();
          std::lock_guard<std::mutex> lock(status_mutex_);
          ++dropped_packets_;
        }
        if (Clock::now() >= deadline) return unavailable(unavailable_message());
        continue;
      }

      if (Clock::now() >= deadline) return unavailable(unavailable_message());
      monitor_->presence().wait_for_change(generation, std::min(deadline, link_.next_deadline()));
    }
  }

  std::string describe() const override {
    const Kinect2Status s = status();
    return "kinect2:" + (s.serial.empty() ? std::string("first found") : s.serial) + " (" +
           s.pipeline + " pipeline, " + to_string(s.state) + ")";
  }

  std::optional<double> nominal_rate_hz() const override { return 30.0; }

  Kinect2Status status() const override {
    std::lock_guard<std::mutex> lock(status_mutex_);
    return status_;
  }

 private:
  static kinect2::DeviceLinkConfig link_config(const Kinect2Options& o) {
    kinect2::DeviceLinkConfig config;
    config.stall_timeout_s = o.stall_timeout_s;
    config.first_frame_timeout_s = o.first_frame_timeout_s;
    config.open_retry_interval_s = o.open_retry_interval_s;
    return config;
  }

  // Feeds presence and the clock to the link and carries out what it asks for.
  void step(uint64_t generation) {
    bool present = monitor_->presence().any_streaming_kinect();
    // A Kinect is attached but not the one with the configured serial: as good as none, until
    // the USB bus changes again.
    if (present && wrong_device_generation_ == generation) present = false;
    run(link_.on_presence(present, Clock::now()));
    run(link_.on_tick(Clock::now()));
    publish_status();
  }

  void run(LinkAction action) {
    while (action != LinkAction::kNone) {
      switch (action) {
        case LinkAction::kOpen: {
          const uint64_t generation = monitor_->presence().generation();
          const Status opened = open_device();
          if (opened.is_ok()) {
            action = link_.on_opened(Clock::now());
          } else {
            if (opened.code() == StatusCode::kNotFound) {
              wrong_device_generation_ = generation;
              (void)link_.on_presence(false, Clock::now());
            }
            action = link_.on_open_failed(opened.message(), Clock::now());
          }
          break;
        }
        case LinkAction::kClose:
          close_device();
          action = link_.on_closed(Clock::now());
          break;
        case LinkAction::kResetUsb: {
          const Status reset = reset_device();
          action = link_.on_reset(reset.is_ok(), reset.message(), Clock::now());
          break;
        }
        case LinkAction::kNone:
          break;
      }
    }
    publish_status();
  }

  Status open_device() {
    kinect2::clear_last_freenect2_error();
    if (!context_) context_ = std::make_unique<libfreenect2::Freenect2>();
    const int count = context_->enumerateDevices();
    std::vector<std::string> serials;
    for (int i = 0; i < count; ++i) serials.push_back(context_->getDeviceSerialNumber(i));
    if (serials.empty())
      return unavailable("a Kinect V2 is on USB but libfreenect2 could not open it" +
                         freenect2_reason() +
                         " (if this says LIBUSB_ERROR_ACCESS, install the udev rule: see "
                         "docs/kinect2.md)");
    const std::string serial = options_.serial.empty() ? serials.front() : options_.serial;
    if (std::find(serials.begin(), serials.end(), serial) == serials.end())
      return not_found("no Kinect V2 with serial " + serial + " is attached (attached: " +
                       joined(serials) + ")");

    auto pipeline = kinect2::make_packet_pipeline(options_.pipeline);
    if (!pipeline.is_ok()) return pipeline.status();
    // The depthfuse pipeline: raw packets, and the P0 tables once start() has read them.
    auto* raw_packets = dynamic_cast<libfreenect2::DumpPacketPipeline*>(pipeline.value().get());
    // openDevice takes ownership of the pipeline, also when it fails.
    libfreenect2::Freenect2Device* device = context_->openDevice(serial, pipeline.value().release());
    if (device == nullptr)
      return unavailable("libfreenect2 could not open Kinect V2 " + serial + freenect2_reason());

    auto listener = std::make_unique<libfreenect2::SyncMultiFrameListener>(
        libfreenect2::Frame::Color | libfreenect2::Frame::Depth);
    device->setColorFrameListener(listener.get());
    device->setIrAndDepthFrameListener(listener.get());
    libfreenect2::Freenect2Device::Config config;
    config.MinDepth = static_cast<float>(options_.min_depth_m);
    config.MaxDepth = static_cast<float>(options_.max_depth_m);
    config.EnableBilateralFilter = options_.bilateral_filter;
    config.EnableEdgeAwareFilter = options_.edge_aware_filter;
    device->setConfiguration(config);

    auto discard = [&](const Status& why) {
      device->stop();
      device->close();
      delete device;
      return why;
    };
    if (!device->start())
      return discard(unavailable("could not start the streams of Kinect V2 " + serial +
                                 freenect2_reason()));

    // start() has read the factory calibration and the P0 tables from the device.
    const std::string device_serial = device->getSerialNumber();
    libfreenect2::Freenect2Device::IrCameraParams ir = device->getIrCameraParams();
    std::unique_ptr<kinect2::PacketDecoding> packet_decoding;
    if (raw_packets != nullptr) {
      size_t p0_size = 0;
      const unsigned char* p0 = raw_packets->getDepthP0Tables(&p0_size);
      kinect2::DepthDecoderOptions decoder;
      decoder.min_depth_m = static_cast<float>(options_.min_depth_m);
      decoder.max_depth_m = static_cast<float>(options_.max_depth_m);
      decoder.bilateral_filter = options_.bilateral_filter;
      decoder.edge_aware_filter = options_.edge_aware_filter;
      decoder.threads = options_.decoder_threads;
      // The factory parameters, from which libfreenect2's pipelines build their tables too.
      auto decoding = kinect2::PacketDecoding::create(p0, p0 == nullptr ? 0 : p0_size, ir, decoder);
      if (!decoding.is_ok())
        return discard(decoding.status().with_context("Kinect V2 " + device_serial));
      packet_decoding = std::move(decoding).value();
    }
    for (const DeviceCalibration& calibration : options_.calibrations)
      if (calibration.serial == device_serial)
        ir = kinect2::with_calibrated_pinhole(ir, calibration.intrinsics);
    auto assembly = kinect2::FrameAssembly::create(ir, device->getColorCameraParams(),
                                                   device_serial, std::move(packet_decoding));
    if (!assembly.is_ok())
      return discard(assembly.status().with_context("Kinect V2 " + device_serial));

    device_ = device;
    listener_ = std::move(listener);
    assembly_ = std::move(assembly).value();
    device_serial_ = device_serial;
    session_started_ = false;
    return Status::ok();
  }

  void close_device() {
    if (device_ != nullptr) {
      device_->stop();
      device_->close();
      delete device_;  // before the listener it writes to
      device_ = nullptr;
    }
    listener_.reset();
    assembly_.reset();
  }

  Status reset_device() {
    // A fresh libusb context for libfreenect2 afterwards: nothing of the hung session survives.
    close_device();
    context_.reset();
    const std::string serial = device_serial_.empty() ? options_.serial : device_serial_;
    Result<int> reset = kinect2::reset_usb_devices(kinect2::kinect2_usb_ids(), serial);
    return reset.is_ok() ? Status::ok() : reset.status();
  }

  // Our sequence continues across reopens; within a session it follows the device's, so that
  // frames the depth decoder dropped show up as gaps.
  uint32_t sequence_for(uint32_t device_sequence) {
    if (!session_started_) {
      session_started_ = true;
      session_first_device_sequence_ = device_sequence;
      session_base_ = next_sequence_;
    }
    uint32_t sequence = session_base_ + (device_sequence - session_first_device_sequence_);
    if (static_cast<int32_t>(sequence - next_sequence_) < 0) {  // the device restarted its count
      session_first_device_sequence_ = device_sequence;
      session_base_ = next_sequence_;
      sequence = next_sequence_;
    }
    next_sequence_ = sequence + 1;
    return sequence;
  }

  Result<Frame> convert(const libfreenect2::FrameMap& frames) {
    const auto depth = frames.find(libfreenect2::Frame::Depth);
    if (depth == frames.end() || depth->second == nullptr)
      return corrupt("libfreenect2 delivered a frame set without depth");
    const auto color = frames.find(libfreenect2::Frame::Color);
    Result<Frame> frame =
        assembly_->assemble(*depth->second, color == frames.end() ? nullptr : color->second);
    if (frame.is_ok()) frame->sequence = sequence_for(frame->sequence);
    return frame;
  }

  std::string unavailable_message() const {
    const Kinect2Status s = status();
    std::string message;
    if (s.state == Kinect2State::kWaitingForDevice) {
      message = "no Kinect V2" +
                (options_.serial.empty() ? std::string() : " with serial " + options_.serial) +
                " is available (" + s.detail + "); waiting for one to be plugged in (" +
                (s.usb_hotplug ? "USB hotplug events" : "polling the USB bus") + ")";
      const std::string watch_error = monitor_->presence().watch_error();
      if (!watch_error.empty()) message += "; USB watcher: " + watch_error;
    } else {
      message = "Kinect V2 " + (s.serial.empty() ? std::string("(first found)") : s.serial) +
                " " + to_string(s.state) + ": " + s.detail;
    }
    if (!last_frame_error_.empty()) message += "; last bad frame: " + last_frame_error_;
    return message;
  }

  void fill_status_locked() {
    status_.state = link_.state();
    status_.detail = link_.detail();
    status_.serial = device_serial_.empty() ? options_.serial : device_serial_;
    status_.pipeline = options_.pipeline;
    status_.usb_hotplug = monitor_->uses_hotplug_events();
    status_.frames = delivered_;
    status_.stalls = link_.stalls();
    status_.usb_resets = link_.usb_resets();
    status_.reconnects = link_.reconnects();
    status_.dropped_packets = dropped_packets_;
  }

  void publish_status() {
    std::lock_guard<std::mutex> lock(status_mutex_);
    fill_status_locked();
  }

  const Kinect2Options options_;
  std::unique_ptr<kinect2::UsbHotplugMonitor> monitor_;
  DeviceLink link_;
  std::unique_ptr<libfreenect2::Freenect2> context_;  // created on the first open
  libfreenect2::Freenect2Device* device_ = nullptr;   // owned; deleted in close_device()
  std::unique_ptr<libfreenect2::SyncMultiFrameListener> listener_;
  std::unique_ptr<kinect2::FrameAssembly> assembly_;  // while a device is open
  std::string device_serial_;
  uint64_t wrong_device_generation_ = UINT64_MAX;
  bool session_started_ = false;
  uint32_t session_first_device_sequence_ = 0;
  uint32_t session_base_ = 0;
  uint32_t next_sequence_ = 0;
  uint64_t delivered_ = 0;
  uint64_t dropped_packets_ = 0;  // guarded by status_mutex_
  std::string last_frame_error_;

  mutable std::mutex status_mutex_;
  Kinect2Status status_;
};

}  // namespace

std::string Kinect2Status::summary() const {
  char counters[160];
  std::snprintf(counters, sizeof(counters),
                "%llu frames, %u stalls, %u USB resets, %u reconnects",
                static_cast<unsigned long long>(frames), stalls, usb_resets, reconnects);
  return std::string(to_string(state)) + ": " + detail + " (serial " +
         (serial.empty() ? std::string("any") : serial) + ", " + pipeline + " pipeline, " +
         counters + ")";
}

Result<Kinect2Options> kinect2_options_from_config(const std::string& serial_or_empty,
                                                   const AppConfig& config) {
  Kinect2Options options;
  options.serial = serial_or_empty;
  options.pipeline = config.capture.kinect2_pipeline;
  options.min_depth_m = config.capture.kinect2_min_depth_m;
  options.max_depth_m = config.capture.kinect2_max_depth_m;
  options.bilateral_filter = config.capture.kinect2_bilateral_filter;
  options.edge_aware_filter = config.capture.kinect2_edge_aware_filter;
  options.decoder_threads = config.capture.kinect2_decoder_threads;
  options.stall_timeout_s = config.capture.kinect2_stall_timeout_s;
  // The first frame needs the firmware handshake and the decoder's tables: allow more.
  options.first_frame_timeout_s = std::max(10.0, 2.0 * options.stall_timeout_s);
  options.calibrations = config.devices;
  DF_RETURN_IF_ERROR(validate(options));
  return options;
}

Result<std::unique_ptr<Kinect2Source>> open_kinect2(const Kinect2Options& options) {
  DF_RETURN_IF_ERROR(validate(options));
  kinect2::install_freenect2_log();
  auto monitor = kinect2::UsbHotplugMonitor::start(kinect2::UsbHotplugConfig{});
  if (!monitor.is_ok()) return monitor.status().with_context("kinect2 source");
  return std::unique_ptr<Kinect2Source>(
      new Kinect2SourceImpl(options, std::move(monitor).value()));
}

Result<std::unique_ptr<FrameSource>> open_kinect2_source(const std::string& serial_or_empty,
                                                         const AppConfig& config) {
  auto options = kinect2_options_from_config(serial_or_empty, config);
  if (!options.is_ok()) return options.status();
  auto source = open_kinect2(options.value());
  if (!source.is_ok()) return source.status();
  return std::unique_ptr<FrameSource>(std::move(source).value());
}

const Kinect2Source* as_kinect2_source(const FrameSource& source) {
  return dynamic_cast<const Kinect2Source*>(&source);
}

}  // namespace depthfuse::kinect2
