// A plausible Kinect V2 for packets made without hardware (the simulated sensor kinect2sim, the
// decoder's tests and benchmark): P0 tables near those a device reports, varying smoothly, and a
// Kinect V2's typical IR calibration.
#pragma once

#include "depthfuse/kinect2/raw_depth.hpp"

namespace depthfuse::kinect2 {

P0Tables simulated_p0_tables();
IrCalibration simulated_ir_calibration();

}  // namespace depthfuse::kinect2
