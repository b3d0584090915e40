// Which Kinect V2 USB devices are attached right now, as a thread-safe registry that a hotplug
// thread feeds (arrivals and departures) and a capture thread waits on. Pure C++: no libusb here,
// so the bookkeeping can be fed events in tests.
#pragma once

#include <chrono>
#include <condition_variable>
#include <cstdint>
#include <mutex>
#include <string>
#include <vector>

namespace depthfuse::kinect2 {

struct UsbId {
  uint16_t vendor_id = 0;
  uint16_t product_id = 0;
};

constexpr uint16_t kMicrosoftVendorId = 0x045e;
constexpr uint16_t kKinect2ProductIdPreview = 0x02c4;  // developer preview sensor
constexpr uint16_t kKinect2ProductId = 0x02d8;         // Kinect for Windows v2 / Xbox One sensor
constexpr uint16_t kKinect2ProductIdOther = 0x02d9;    // also in libfreenect2's udev rule; not streamed

// The three ids of the udev rule (systemd/): all are watched for hotplug.
std::vector<UsbId> kinect2_usb_ids();
// True for the ids libfreenect2 can open and stream from (02c4, 02d8).
bool is_kinect2_streaming_id(uint16_t vendor_id, uint16_t product_id);
// "045e:02d8"
std::string to_string(const UsbId& id);

// One attached device. bus + address identify it while it stays plugged in.
struct UsbDeviceRecord {
  uint8_t bus = 0;
  uint8_t address = 0;
  uint16_t vendor_id = 0;
  uint16_t product_id = 0;
};

class UsbPresence {
 public:
  using Clock = std::chrono::steady_clock;

  // A device appeared / disappeared. Both bump generation() and wake waiters.
  void arrived(const UsbDeviceRecord& device);
  void left(const UsbDeviceRecord& device);
  // A complete snapshot (from polling when libusb has no hotplug support). Bumps generation() only
  // when the set of devices changed.
  void replace_all(const std::vector<UsbDeviceRecord>& devices);
  // The watcher broke (e.g. its libusb event loop failed): recorded for status messages, wakes
  // waiters. An empty string clears it.
  void set_watch_error(const std::string& error);

  std::vector<UsbDeviceRecord> devices() const;
  // At least one device libfreenect2 can stream from (045e:02c4 or 045e:02d8) is attached.
  bool any_streaming_kinect() const;
  uint64_t generation() const;
  std::string watch_error() const;

  // Blocks until generation() differs from `seen_generation` or until `deadline`, whichever comes
  // first, and returns generation(). Never spins: it sleeps on a condition variable.
  uint64_t wait_for_change(uint64_t seen_generation, Clock::time_point deadline) const;

 private:
  void bump_locked();

  mutable std::mutex mutex_;
  mutable std::condition_variable changed_;
  std::vector<UsbDeviceRecord> devices_;
  uint64_t generation_ = 0;
  std::string watch_error_;
};

}  // namespace depthfuse::kinect2
