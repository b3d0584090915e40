#include "depthfuse/kinect2/usb_hotplug.hpp"

#include <libusb.h>

#include <algorithm>
#include <atomic>
#include <chrono>
#include <condition_variable>
#include <mutex>
#include <string>
#include <thread>

namespace depthfuse::kinect2 {

namespace {

UsbDeviceRecord record_of(libusb_device* device) {
  UsbDeviceRecord record;
  record.bus = libusb_get_bus_number(device);
  record.address = libusb_get_device_address(device);
  libusb_device_descriptor descriptor{};
  // Cached by libusb since 1.0.16: always succeeds, also for a device that just left.
  if (libusb_get_device_descriptor(device, &descriptor) == LIBUSB_SUCCESS) {
    record.vendor_id = descriptor.idVendor;
    record.product_id = descriptor.idProduct;
  }
  return record;
}

bool matches(const std::vector<UsbId>& ids, const UsbDeviceRecord& record) {
  return std::any_of(ids.begin(), ids.end(), [&](const UsbId& id) {
    return id.vendor_id == record.vendor_id && id.product_id == record.product_id;
  });
}

std::string libusb_message(int code) {
  return std::string(libusb_error_name(code)) + " (" + libusb_strerror(code) + ")";
}

}  // namespace

struct UsbHotplugMonitor::Impl {
  UsbHotplugConfig config;
  libusb_context* context = nullptr;
  std::vector<libusb_hotplug_callback_handle> callbacks;
  bool hotplug = false;
  UsbPresence presence;
  std::thread thread;
  std::atomic<bool> stop{false};
  std::mutex stop_mutex;
  std::condition_variable stop_cv;

  ~Impl() {
    stop = true;
    if (context != nullptr && hotplug) libusb_interrupt_event_handler(context);
    stop_cv.notify_all();
    if (thread.joinable()) thread.join();
    if (context != nullptr) {
      for (auto handle : callbacks) libusb_hotplug_deregister_callback(context, handle);
      libusb_exit(context);
    }
  }

  static int LIBUSB_CALL on_hotplug(libusb_context*, libusb_device* device,
                                    libusb_hotplug_event event, void* user_data) {
    auto* self = static_cast<Impl*>(user_data);
    const UsbDeviceRecord record = record_of(device);
    if (event == LIBUSB_HOTPLUG_EVENT_DEVICE_ARRIVED)
      self->presence.arrived(record);
    else if (event == LIBUSB_HOTPLUG_EVENT_DEVICE_LEFT)
      self->presence.left(record);
    return 0;  // stay registered
  }

  std::vector<UsbDeviceRecord> snapshot(std::string* error) const {
    std::vector<UsbDeviceRecord> found;
    libusb_device** list = nullptr;
    const ssize_t count = libusb_get_device_list(context, &list);
    if (count < 0) {
      *error = "libusb_get_device_list failed: " + libusb_message(static_cast<int>(count));
      return found;
    }
    for (ssize_t i = 0; i < count; ++i) {
      const UsbDeviceRecord record = record_of(list[i]);
      if (matches(config.ids, record)) found.push_back(record);
    }
    libusb_free_device_list(list, 1);
    error->clear();
    return found;
  }

  void event_loop() {
    using Clock = std::chrono::steady_clock;
    const auto rescan_interval = std::chrono::duration_cast<Clock::duration>(
        std::chrono::duration<double>(config.rescan_interval_s));
    auto next_rescan = Clock::now() + rescan_interval;
    while (!stop) {
      // Sleeps in libusb until an event, the next rescan or 1 s; libusb_interrupt_event_handler
      // wakes it early on shutdown.
      const auto until_rescan = std::chrono::duration_cast<std::chrono::microseconds>(
          next_rescan - Clock::now());
      const int64_t wait_us =
          std::clamp<int64_t>(until_rescan.count(), 0, int64_t{1000000});
      timeval timeout{static_cast<time_t>(wait_us / 1000000),
                      static_cast<suseconds_t>(wait_us % 1000000)};
      const int r = libusb_handle_events_timeout_completed(context, &timeout, nullptr);
      if (r < 0 && r != LIBUSB_ERROR_INTERRUPTED) {
        presence.set_watch_error("libusb event handling failed: " + libusb_message(r));
        std::unique_lock<std::mutex> lock(stop_mutex);
        stop_cv.wait_for(lock, std::chrono::seconds(1), [&] { return stop.load(); });
        continue;
      }
      if (Clock::now() >= next_rescan) {
        // Callbacks run on this thread too, so a snapshot never races with an event.
        std::string error;
        const auto devices = snapshot(&error);
        if (error.empty()) presence.replace_all(devices);
        presence.set_watch_error(error);  // also clears an earlier event-loop error
        next_rescan = Clock::now() + rescan_interval;
      }
    }
  }

  void poll_loop() {
    const auto interval = std::chrono::duration<double>(config.poll_interval_s);
    while (!stop) {
      std::string error;
      const auto devices = snapshot(&error);
      if (error.empty()) presence.replace_all(devices);
      presence.set_watch_error(error);
      std::unique_lock<std::mutex> lock(stop_mutex);
      stop_cv.wait_for(lock, interval, [&] { return stop.load(); });
    }
  }
};

UsbHotplugMonitor::UsbHotplugMonitor(std::unique_ptr<Impl> impl) : impl_(std::move(impl)) {}
UsbHotplugMonitor::~UsbHotplugMonitor() = default;

const UsbPresence& UsbHotplugMonitor::presence() const { return impl_->presence; }
bool UsbHotplugMonitor::uses_hotplug_events() const { return impl_->hotplug; }

Result<std::unique_ptr<UsbHotplugMonitor>> UsbHotplugMonitor::start(
    const UsbHotplugConfig& config) {
  if (config.ids.empty()) return invalid_argument("USB hotplug monitor: no vendor:product ids");
  if (!(config.poll_interval_s > 0.0))
    return invalid_argument("USB hotplug monitor: poll_interval_s must be > 0, got " +
                            std::to_string(config.poll_interval_s));
  if (!(config.rescan_interval_s > 0.0))
    return invalid_argument("USB hotplug monitor: rescan_interval_s must be > 0, got " +
                            std::to_string(config.rescan_interval_s));

  auto impl = std::make_unique<Impl>();
  impl->config = config;
  const int r = libusb_init(&impl->context);
  if (r != LIBUSB_SUCCESS) {
    impl->context = nullptr;
    return unavailable("USB is not accessible: libusb_init failed: " + libusb_message(r));
  }

  impl->hotplug = !config.force_polling && libusb_has_capability(LIBUSB_CAP_HAS_HOTPLUG) != 0;
  if (impl->hotplug) {
    for (const UsbId& id : config.ids) {
      libusb_hotplug_callback_handle handle{};
      const int rr = libusb_hotplug_register_callback(
          impl->context,
          static_cast<libusb_hotplug_event>(LIBUSB_HOTPLUG_EVENT_DEVICE_ARRIVED |
                                            LIBUSB_HOTPLUG_EVENT_DEVICE_LEFT),
          LIBUSB_HOTPLUG_ENUMERATE, id.vendor_id, id.product_id, LIBUSB_HOTPLUG_MATCH_ANY,
          &Impl::on_hotplug, impl.get(), &handle);
      if (rr != LIBUSB_SUCCESS) {
        // Fall back to polling rather than fail: waiting for the device must keep working.
        for (auto h : impl->callbacks) libusb_hotplug_deregister_callback(impl->context, h);
        impl->callbacks.clear();
        impl->hotplug = false;
        break;
      }
      impl->callbacks.push_back(handle);
    }
  }

  if (impl->hotplug) {
    impl->thread = std::thread([p = impl.get()] { p->event_loop(); });
  } else {
    std::string error;
    impl->presence.replace_all(impl->snapshot(&error));  // report what is there before returning
    impl->presence.set_watch_error(error);
    impl->thread = std::thread([p = impl.get()] { p->poll_loop(); });
  }
  return std::unique_ptr<UsbHotplugMonitor>(new UsbHotplugMonitor(std::move(impl)));
}

}  // namespace depthfuse::kinect2
