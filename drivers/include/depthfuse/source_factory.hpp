// Opens any FrameSource from a spec string, as given on command lines and in the config:
//   tum:<folder>             a TUM RGB-D folder (replay driver)
//   synthetic:<corner|room|rooms>[?frames=N&seed=S&pose_noise_m=X&pose_noise_deg=Y]
//   kinect2[:serial]         a live Kinect V2 (only where libfreenect2 was found at build time)
//   lcmlog:<file>            a session recorded with lcm-logger
#pragma once

#include <memory>
#include <optional>
#include <string>

#include "depthfuse/app_config.hpp"
#include "depthfuse/frame_source.hpp"

namespace depthfuse {

Result<std::unique_ptr<FrameSource>> open_frame_source(const std::string& spec,
                                                       const AppConfig& config);

// For a live device source that open_frame_source has not opened yet, the device status to report
// meanwhile, `detail` saying why ("" while opening it; else why it could not, kUnavailable: its bus
// is not accessible for now, which is worth waiting for). nullopt when `spec` names no device
// source that is built in.
std::optional<DeviceStatus> device_status_before_open(const std::string& spec,
                                                      const AppConfig& config,
                                                      const std::string& detail);

}  // namespace depthfuse
