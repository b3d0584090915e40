// Watches the USB bus for Kinect V2 devices with libusb hotplug callbacks
// (libusb_hotplug_register_callback for 045e:02c4, 045e:02d8 and 045e:02d9) on a thread of its own,
// and keeps a UsbPresence up to date. Where libusb has no hotplug support it polls the device list
// instead. Either way nobody spins: the thread sleeps in libusb's event wait (or between polls) and
// consumers sleep in UsbPresence::wait_for_change.
#pragma once

#include <memory>
#include <vector>

#include "depthfuse/kinect2/usb_presence.hpp"
#include "depthfuse/status.hpp"

namespace depthfuse::kinect2 {

struct UsbHotplugConfig {
  std::vector<UsbId> ids = kinect2_usb_ids();
  double poll_interval_s = 1.0;  // only without hotplug support (or when forced below)
  // With hotplug events, the bus is also rescanned this often: a safety net should an event be
  // lost (e.g. no udev or netlink events inside a container). Rescans that find no change are
  // silent.
  double rescan_interval_s = 5.0;
  bool force_polling = false;    // tests and odd platforms: skip hotplug callbacks
};

class UsbHotplugMonitor {
 public:
  // Starts watching. Devices already attached are reported before this returns. kUnavailable
  // when libusb cannot be initialised (no USB on this machine).
  static Result<std::unique_ptr<UsbHotplugMonitor>> start(const UsbHotplugConfig& config);
  ~UsbHotplugMonitor();  // stops and joins the watcher thread

  UsbHotplugMonitor(const UsbHotplugMonitor&) = delete;
  UsbHotplugMonitor& operator=(const UsbHotplugMonitor&) = delete;

  const UsbPresence& presence() const;
  // True when libusb delivers hotplug events, false when the monitor polls.
  bool uses_hotplug_events() const;

  struct Impl;

 private:
  explicit UsbHotplugMonitor(std::unique_ptr<Impl> impl);
  std::unique_ptr<Impl> impl_;
};

}  // namespace depthfuse::kinect2
