// Recovery of a hung Kinect V2: a USB port reset (libusb_reset_device), which makes the device
// drop off the bus and enumerate again, the software equivalent of unplugging it.
#pragma once

#include <string>
#include <vector>

#include "depthfuse/kinect2/usb_presence.hpp"
#include "depthfuse/status.hpp"

namespace depthfuse::kinect2 {

// Resets every attached device with one of `ids` whose USB serial string equals `serial` (every
// device with one of `ids` when `serial` is empty). Returns how many were reset. kNotFound when none
// matched (the message lists what was seen), kIoError naming the device when a reset failed,
// kUnavailable when libusb cannot be initialised. A device that re-enumerates during the reset
// (LIBUSB_ERROR_NOT_FOUND from libusb_reset_device) counts as reset.
Result<int> reset_usb_devices(const std::vector<UsbId>& ids, const std::string& serial);

}  // namespace depthfuse::kinect2
