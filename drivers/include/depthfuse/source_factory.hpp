// Opens any FrameSource from a spec string, as given on command lines and in the config:
//   tum:<folder>             a TUM RGB-D folder (replay driver)
//   synthetic:<corner|room|rooms>[?frames=N&seed=S&pose_noise_m=X&pose_noise_deg=Y]
//   kinect2[:serial]         a live Kinect V2 (only where libfreenect2 was found at build time)
//   lcmlog:<file>            a session recorded with lcm-logger
#pragma once

#include <memory>
#include <string>

#include "depthfuse/app_config.hpp"
#include "depthfuse/frame_source.hpp"

namespace depthfuse {

Result<std::unique_ptr<FrameSource>> open_frame_source(const std::string& spec,
                                                       const AppConfig& config);

}  // namespace depthfuse
