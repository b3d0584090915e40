// kinect2sim: a simulated Kinect V2, so that the capture daemon runs its whole Kinect V2 path on
// any machine where the driver is built. It renders a synthetic scene (drivers/synthetic) with
// the simulated device's pinhole, turns each image into what the depth camera measures (its lens
// distortion, an IR return), encodes that into the raw depth packet the device would send
// (PacketEncoder, with the simulated device's P0 tables and calibration), and hands the packet to
// the driver's own path, as libfreenect2 hands over a real one: depthfuse's decoder, libfreenect2's
// registration (undistortion), metres, the published Frame (FrameAssembly).
//
// Rendering and encoding are done ahead by a producer thread, a few packets at most, so that
// next() costs what a real Kinect's frame costs the capture daemon: decoding and registration.
// With cache_mb=N the packets of the first N MB worth of frames (3 MB each) are kept and reused
// when the sequence loops, so that after the first loop the simulator itself costs next to
// nothing (for measuring the Kinect V2 path and what runs beside it).
#pragma once

#include <memory>
#include <string>

#include "depthfuse/app_config.hpp"
#include "depthfuse/frame_source.hpp"
#include "depthfuse/status.hpp"

namespace depthfuse::kinect2 {

// The factory entry point (drivers/source_factory.cpp): "kinect2sim:<corner|room|rooms>", with
// the synthetic source's options ("?frames=N&seed=S&pose_noise_m=X&pose_noise_deg=Y&rate_hz=R&
// noise=0|1"; the renderer's depth noise is off unless noise=1: the packets' quantisation is the
// sensor's noise), and its own "cache_mb=N" (default 0). The decoder follows the config's
// kinect2_* keys as for a real Kinect.
Result<std::unique_ptr<FrameSource>> open_kinect2sim_source(const std::string& arg,
                                                            const AppConfig& config);

}  // namespace depthfuse::kinect2
