// Internal: the per-frame path before registration and fusion, the same for a live frame, a
// replayed one, a keyframe restored and every pass of the batch loop.
#pragma once

#include <cstddef>

#include "depthfuse/config.hpp"
#include "depthfuse/measurement.hpp"
#include "depthfuse/status.hpp"
#include "depthfuse/types.hpp"

namespace depthfuse {

// Back-projection, normals and (if the method has it) the pre-filter. Returns how many measurements
// the pre-filter removed. `velocity`, where known, undoes a rolling shutter first.
Result<size_t> measure_frame(const Frame& frame, const ReconstructionConfig& config,
                             MeasurementImage* m, const CameraVelocity* velocity = nullptr);

// Why a frame has no valid depth measurement: no depth at all, or none inside the sensor's range.
Status no_measurement(const DepthImage& depth, const SensorModelConfig& sensor);

// The angle of the rotation between two poses, degrees.
double rotation_between_deg(const Pose& a, const Pose& b);

}  // namespace depthfuse
