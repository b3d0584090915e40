#include "depthfuse/kinect2/usb_reset.hpp"

#include <libusb.h>

#include <algorithm>
#include <memory>

namespace depthfuse::kinect2 {

namespace {

std::string libusb_message(int code) {
  return std::string(libusb_error_name(code)) + " (" + libusb_strerror(code) + ")";
}

std::string where(libusb_device* device, const UsbId& id) {
  return to_string(id) + " on bus " + std::to_string(libusb_get_bus_number(device)) +
         " address " + std::to_string(libusb_get_device_address(device));
}

struct ContextCloser {
  void operator()(libusb_context* context) const { libusb_exit(context); }
};
struct ListFreer {
  void operator()(libusb_device** list) const { libusb_free_device_list(list, 1); }
};
struct HandleCloser {
  void operator()(libusb_device_handle* handle) const { libusb_close(handle); }
};

}  // namespace

Result<int> reset_usb_devices(const std::vector<UsbId>& ids, const std::string& serial) {
  libusb_context* raw_context = nullptr;
  const int r = libusb_init(&raw_context);
  if (r != LIBUSB_SUCCESS)
    return unavailable("USB is not accessible: libusb_init failed: " + libusb_message(r));
  std::unique_ptr<libusb_context, ContextCloser> context(raw_context);

  libusb_device** raw_list = nullptr;
  const ssize_t count = libusb_get_device_list(context.get(), &raw_list);
  if (count < 0)
    return io_error("libusb_get_device_list failed: " +
                    libusb_message(static_cast<int>(count)));
  std::unique_ptr<libusb_device*, ListFreer> list(raw_list);

  int reset = 0;
  std::string seen;     // devices with a matching id, for the not-found message
  std::string failure;  // first error
  for (ssize_t i = 0; i < count; ++i) {
    libusb_device* device = raw_list[i];
    libusb_device_descriptor descriptor{};
    if (libusb_get_device_descriptor(device, &descriptor) != LIBUSB_SUCCESS) continue;
    const UsbId id{descriptor.idVendor, descriptor.idProduct};
    const bool wanted = std::any_of(ids.begin(), ids.end(), [&](const UsbId& w) {
      return w.vendor_id == id.vendor_id && w.product_id == id.product_id;
    });
    if (!wanted) continue;

    libusb_device_handle* raw_handle = nullptr;
    const int open_result = libusb_open(device, &raw_handle);
    if (open_result != LIBUSB_SUCCESS) {
      seen += (seen.empty() ? "" : ", ") + where(device, id) + " (cannot open: " +
              libusb_error_name(open_result) + ")";
      if (failure.empty())
        failure = "cannot open " + where(device, id) + " for a reset: " +
                  libusb_message(open_result) +
                  (open_result == LIBUSB_ERROR_ACCESS
                       ? "; is the udev rule (systemd/60-depthfuse-kinect2.rules) installed? See docs/kinect2.md"
                       : "");
      continue;
    }
    std::unique_ptr<libusb_device_handle, HandleCloser> handle(raw_handle);

    std::string device_serial;
    if (descriptor.iSerialNumber != 0) {
      unsigned char buffer[256];
      const int n = libusb_get_string_descriptor_ascii(handle.get(), descriptor.iSerialNumber,
                                                       buffer, sizeof(buffer));
      if (n > 0) device_serial.assign(reinterpret_cast<const char*>(buffer), static_cast<size_t>(n));
    }
    seen += (seen.empty() ? "" : ", ") + where(device, id) +
            (device_serial.empty() ? std::string(" (no serial)") : " serial " + device_serial);
    if (!serial.empty() && device_serial != serial) continue;

    const int reset_result = libusb_reset_device(handle.get());
    if (reset_result == LIBUSB_SUCCESS || reset_result == LIBUSB_ERROR_NOT_FOUND) {
      ++reset;  // NOT_FOUND: it re-enumerated, which is what a reset is for
    } else if (failure.empty()) {
      failure = "libusb_reset_device failed on " + where(device, id) + ": " +
                libusb_message(reset_result);
    }
  }

  if (reset > 0) return reset;
  if (!failure.empty()) return io_error(failure);
  std::string wanted;
  for (const UsbId& id : ids) wanted += (wanted.empty() ? "" : "/") + to_string(id);
  return not_found("no USB device " + wanted +
                   (serial.empty() ? std::string() : " with serial " + serial) +
                   " to reset (seen: " + (seen.empty() ? std::string("none") : seen) + ")");
}

}  // namespace depthfuse::kinect2
