#include "depthfuse/kinect2/usb_presence.hpp"

#include <algorithm>
#include <cstdio>

namespace depthfuse::kinect2 {

std::vector<UsbId> kinect2_usb_ids() {
  return {{kMicrosoftVendorId, kKinect2ProductIdPreview},
          {kMicrosoftVendorId, kKinect2ProductId},
          {kMicrosoftVendorId, kKinect2ProductIdOther}};
}

bool is_kinect2_streaming_id(uint16_t vendor_id, uint16_t product_id) {
  return vendor_id == kMicrosoftVendorId &&
         (product_id == kKinect2ProductId || product_id == kKinect2ProductIdPreview);
}

std::string to_string(const UsbId& id) {
  char text[16];
  std::snprintf(text, sizeof(text), "%04x:%04x", static_cast<unsigned>(id.vendor_id),
                static_cast<unsigned>(id.product_id));
  return text;
}

namespace {

bool same_port(const UsbDeviceRecord& a, const UsbDeviceRecord& b) {
  return a.bus == b.bus && a.address == b.address;
}

bool same_device(const UsbDeviceRecord& a, const UsbDeviceRecord& b) {
  return same_port(a, b) && a.vendor_id == b.vendor_id && a.product_id == b.product_id;
}

}  // namespace

void UsbPresence::bump_locked() {
  ++generation_;
  changed_.notify_all();
}

void UsbPresence::arrived(const UsbDeviceRecord& device) {
  std::lock_guard<std::mutex> lock(mutex_);
  // A new device on a port we still list means we missed its departure: the new one replaces it.
  devices_.erase(std::remove_if(devices_.begin(), devices_.end(),
                                [&](const UsbDeviceRecord& d) { return same_port(d, device); }),
                 devices_.end());
  devices_.push_back(device);
  bump_locked();
}

void UsbPresence::left(const UsbDeviceRecord& device) {
  std::lock_guard<std::mutex> lock(mutex_);
  devices_.erase(std::remove_if(devices_.begin(), devices_.end(),
                                [&](const UsbDeviceRecord& d) { return same_port(d, device); }),
                 devices_.end());
  bump_locked();
}

void UsbPresence::replace_all(const std::vector<UsbDeviceRecord>& devices) {
  std::lock_guard<std::mutex> lock(mutex_);
  const bool unchanged =
      devices.size() == devices_.size() &&
      std::all_of(devices.begin(), devices.end(), [&](const UsbDeviceRecord& d) {
        return std::any_of(devices_.begin(), devices_.end(),
                           [&](const UsbDeviceRecord& e) { return same_device(d, e); });
      });
  if (unchanged) return;
  devices_ = devices;
  bump_locked();
}

void UsbPresence::set_watch_error(const std::string& error) {
  std::lock_guard<std::mutex> lock(mutex_);
  if (watch_error_ == error) return;
  watch_error_ = error;
  bump_locked();
}

std::vector<UsbDeviceRecord> UsbPresence::devices() const {
  std::lock_guard<std::mutex> lock(mutex_);
  return devices_;
}

bool UsbPresence::any_streaming_kinect() const {
  std::lock_guard<std::mutex> lock(mutex_);
  return std::any_of(devices_.begin(), devices_.end(), [](const UsbDeviceRecord& d) {
    return is_kinect2_streaming_id(d.vendor_id, d.product_id);
  });
}

uint64_t UsbPresence::generation() const {
  std::lock_guard<std::mutex> lock(mutex_);
  return generation_;
}

std::string UsbPresence::watch_error() const {
  std::lock_guard<std::mutex> lock(mutex_);
  return watch_error_;
}

uint64_t UsbPresence::wait_for_change(uint64_t seen_generation, Clock::time_point deadline) const {
  std::unique_lock<std::mutex> lock(mutex_);
  changed_.wait_until(lock, deadline, [&] { return generation_ != seen_generation; });
  return generation_;
}

}  // namespace depthfuse::kinect2
