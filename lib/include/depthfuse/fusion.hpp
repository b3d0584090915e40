// Fusion of one measured depth map into the map by the paper's merge rule, the visibility
// violation count, and the post-filter.
#pragma once

#include <cstdint>
#include <memory>

#include "depthfuse/config.hpp"
#include "depthfuse/measurement.hpp"
#include "depthfuse/point_map.hpp"
#include "depthfuse/sensor_model.hpp"

namespace depthfuse {

struct FusionStats {
  size_t measurements = 0;  // valid measurements offered
  size_t merged = 0;        // refined an existing point
  size_t added = 0;         // became a new point
  size_t violations = 0;    // existing points seen through
  size_t redundant = 0;     // did not merge, but an existing point explains it: dropped
};

// The merge rule in one place: merges the new measurement (p_n, information L_n) into the existing
// point (p_e, L_e) if the fused point lies inside both uncertainty ellipsoids. On success writes the
// fused position and information and returns true.
bool merge_measurement(const Eigen::Vector3f& p_e, const Eigen::Matrix3f& L_e,
                       const Eigen::Vector3f& p_n, const Eigen::Matrix3f& L_n,
                       Eigen::Vector3f* p_fused, Eigen::Matrix3f* L_fused);

class ModelProjection;  // internal: the map rendered into a camera

// Fuses depth maps into a map. Holds scratch buffers so that nothing is allocated per point.
class Fuser {
 public:
  Fuser(const SensorModelConfig& sensor, const FusionConfig& fusion);
  ~Fuser();
  Fuser(const Fuser&) = delete;
  Fuser& operator=(const Fuser&) = delete;

  // frame_id must increase from call to call (points and chunks record the last frame that
  // touched them); color may be null.
  FusionStats fuse(const MeasurementImage& m, const ColorImage* color, const Pose& T_world_cam,
                   uint32_t frame_id, PointMap* map);

 private:
  struct Scratch;  // per-frame buffers, kept so that nothing is allocated per frame
  SensorModelConfig sensor_config_;
  FusionConfig config_;
  std::unique_ptr<ModelProjection> projection_;
  std::unique_ptr<Scratch> scratch_;
};

// Removes points whose visibility violations outnumber their merges. Returns how many.
size_t postfilter(PointMap* map);

}  // namespace depthfuse
