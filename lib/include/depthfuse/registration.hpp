// Re-registration: point-to-plane ICP of one depth map against the fused map.
#pragma once

#include <memory>

#include "depthfuse/config.hpp"
#include "depthfuse/measurement.hpp"
#include "depthfuse/point_map.hpp"

namespace depthfuse {

struct RegistrationResult {
  Pose T_world_cam = Pose::Identity();  // refined
  bool converged = false;               // enough correspondences at the end
  size_t correspondences = 0;
  double fitness = 0.0;                 // inlier correspondences / valid measurements used
  double rmse_m = 0.0;                  // point-to-plane residual of the inliers
  int iterations = 0;
};

class ModelProjection;

class Registrar {
 public:
  explicit Registrar(const RegistrationConfig& config);
  ~Registrar();
  Registrar(const Registrar&) = delete;
  Registrar& operator=(const Registrar&) = delete;

  // `iterations` ICP steps at full resolution (the paper's re-registration).
  RegistrationResult refine(const MeasurementImage& m, const PointMap& map,
                            const Pose& T_world_cam_initial);
  // Coarse-to-fine for larger motions (tracking without a pose hint).
  RegistrationResult track(const MeasurementImage& m, const PointMap& map,
                           const Pose& T_world_cam_initial);

 private:
  // Projects the map around the frame's measurements into the camera at T_world_cam.
  void render_model(const MeasurementImage& m, const PointMap& map, const Pose& T_world_cam,
                    double max_corr_m);
  // ICP against the last rendered model, from `initial`.
  RegistrationResult run(const MeasurementImage& m, const Pose& initial, int subsample,
                         int iterations, double max_corr_m);
  RegistrationConfig config_;
  std::unique_ptr<ModelProjection> projection_;
  Pose T_world_model_cam_ = Pose::Identity();  // where the model was rendered from
  CameraIntrinsics model_K_;                    // and with which camera
};

}  // namespace depthfuse
