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

// The fused surface as one camera sees it: per pixel a world point and unit normal, or nothing
// (w = 0). ICP aligns a depth map to this.
struct SurfaceView {
  struct Pixel {
    float x, y, z;     // world frame, m
    float nx, ny, nz;  // unit normal, world frame
    float w;           // confidence weight; 0: no surface at this pixel
  };
  CameraIntrinsics K;                   // the camera the view was made with
  Pose T_world_cam = Pose::Identity();  // and where it was
  std::vector<Pixel> pixels;            // K.width * K.height, row by row

  bool empty() const { return pixels.empty(); }
  void clear() { pixels.clear(); }
};

class ModelProjection;

class Registrar {
 public:
  explicit Registrar(const RegistrationConfig& config);
  ~Registrar();
  Registrar(const Registrar&) = delete;
  Registrar& operator=(const Registrar&) = delete;

  // `iterations` ICP steps at full resolution (the paper's re-registration), against the map
  // rendered at the initial pose.
  RegistrationResult refine(const MeasurementImage& m, const PointMap& map,
                            const Pose& T_world_cam_initial);
  // Coarse-to-fine for larger motions (tracking without a pose hint).
  RegistrationResult track(const MeasurementImage& m, const PointMap& map,
                           const Pose& T_world_cam_initial);

  // The same against a view of the map made before, e.g. model() for the next frame.
  // Associations go through the view's camera, whatever the current estimate.
  RegistrationResult refine(const MeasurementImage& m, const SurfaceView& model,
                            const Pose& T_world_cam_initial);
  RegistrationResult track(const MeasurementImage& m, const SurfaceView& model,
                           const Pose& T_world_cam_initial);

  // The model the last refine() or track() against the map rendered (empty before any).
  const SurfaceView& model() const { return view_; }

 private:
  // Projects the map around the frame's measurements into the camera at T_world_cam: view_, the
  // consensus surface of the points within band_m behind the front-most, for pairs up to max_corr_m.
  void render_model(const MeasurementImage& m, const PointMap& map, const Pose& T_world_cam,
                    double band_m, double max_corr_m);
  // ICP against `model`, from `initial`, on every `subsample`-th pixel. Fewer than `min_pairs`
  // (at least 6) inlier pairs: not converged, the initial pose stays.
  RegistrationResult run(const MeasurementImage& m, const SurfaceView& model, const Pose& initial,
                         int subsample, int iterations, double max_corr_m, size_t min_pairs);
  // Inlier pairs a level of coarse-to-fine needs (level 0: refine() and the finest level).
  size_t min_pairs(int level) const;
  // Coarse to fine: every level halves the pixel step and the correspondence gate and needs four
  // times the pairs (registration.min_correspondences at the finest).
  RegistrationResult coarse_to_fine(const MeasurementImage& m, const SurfaceView& model,
                                    const Pose& T_world_cam_initial);
  RegistrationConfig config_;
  std::unique_ptr<ModelProjection> projection_;
  SurfaceView view_;  // the last rendered model
};

}  // namespace depthfuse
