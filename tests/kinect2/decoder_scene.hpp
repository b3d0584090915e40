// Test input for the depth decoder: a plausible device (simulated_device.hpp) and a synthetic
// scene with what the decoder must handle: planes and a sphere at several depths, sharp depth
// edges (flying pixels), weak and saturated pixels, and depths outside [0.5, 4.5] m.
#pragma once

#include "depthfuse/kinect2/depth_decoder.hpp"
#include "depthfuse/kinect2/raw_depth.hpp"
#include "depthfuse/kinect2/simulated_device.hpp"
#include "depthfuse/types.hpp"

namespace depthfuse::kinect2::test {

struct SceneImages {
  DepthImage depth;  // metres, libfreenect2's orientation, 0 = no return
  IrImage ir;        // amplitude; >= 65535 saturated
};
// `variant` shifts the scene a little (successive frames).
SceneImages scene_images(int variant = 0);

}  // namespace depthfuse::kinect2::test
