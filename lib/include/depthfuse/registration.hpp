// Re-registration: point-to-plane ICP of one depth map against the fused map.
#pragma once

#include <memory>
#include <optional>

#include "depthfuse/config.hpp"
#include "depthfuse/measurement.hpp"
#include "depthfuse/point_map.hpp"
#include "depthfuse/pose_delta.hpp"

namespace depthfuse {

struct RegistrationResult {
  Pose T_world_cam = Pose::Identity();  // refined
  bool converged = false;               // enough correspondences at the end
  size_t correspondences = 0;
  double fitness = 0.0;                 // inlier correspondences / valid measurements used
  // Inlier correspondences / valid measurements used that fall on the model's surface: how much of
  // the frame agrees with the map where the map has something to say. A view of unmapped space
  // lowers the fitness but not this; a camera placed where it is not lowers both.
  double model_fitness = 0.0;
  double rmse_m = 0.0;                  // point-to-plane residual of the inliers
  // The robust (Huber) cost per sampled measurement, a measurement without a pair counted as one
  // at the correspondence gate: lower is better. Compares two starts of one frame.
  double mean_cost = 0.0;
  // The smallest eigenvalue of the normal equations over the largest (rotations in metres at the
  // pairs' lever arm), at the last iteration: near 0, some direction of the pose is unconstrained.
  double conditioning = 0.0;
  int iterations = 0;
  // What the depth said of the pose, in the camera frame (pose_delta.hpp: rotation first): the
  // normal equations of the last iteration as an information matrix, weighted by the residuals'
  // noise and registration.model_error_m. A direction the view does not constrain has (almost)
  // none. Zero when not converged.
  Matrix6d information = Matrix6d::Zero();
  // The pose's covariance, same frame: of the information and the motion prior's together, or of
  // the information alone (directions without any capped at 1 m / 1 rad).
  Matrix6d covariance = Matrix6d::Identity();
  // Tracked with a motion prior: the depth's smallest share of the estimate over all directions (1:
  // the depth alone decided, 0: the motion model alone), 1 without one.
  bool motion_prior = false;
  double data_share = 1.0;
  // With a motion prior: how far the depth moved the estimate from the prediction (pose_delta from
  // the prediction, its camera frame) and that difference's chi-square under the prior; zero
  // without one.
  Vector6d prior_innovation = Vector6d::Zero();
  double prior_chi2 = 0.0;
};

// The motion model's prediction of a frame's pose and how far to trust it: a Gaussian prior on the
// pose in tracking's normal equations, so that the estimate is a MAP one. Where the depth does not
// constrain a direction (a camera sliding along a long sofa), the pose follows the motion model
// there; where it does, the depth decides.
struct MotionPrior {
  Pose T_world_cam = Pose::Identity();  // the prediction
  // Of the pose about the prediction, in its camera frame (pose_delta.hpp), 1/rad^2 and 1/m^2.
  // Positive definite.
  Matrix6d information = Matrix6d::Identity();
};

// How far a frame's tracked pose can be trusted (registration.tracking_* in config/depthfuse.toml).
enum class TrackingState {
  kTracked,    // ICP converged with a good fitness and residual, every direction constrained
  kUncertain,  // converged, but with a poor fitness or a direction the view hardly constrains
  kLost,       // no convergence, too few pairs or too large a residual: the pose is unknown
};
const char* to_string(TrackingState s);
// model_fitness_reference: the model fitness this camera's frames have shown lately when tracked
// (IncrementalReconstructor keeps it; 1 before any): the lost rule's threshold is
// c.tracking_lost_model_fitness times it, since how well a correctly placed frame agrees with the
// map depends on the sensor's noise and the scene (synthetic frames 0.997, TUM fr1/xyz 0.84).
TrackingState classify_tracking(const RegistrationResult& r, const RegistrationConfig& c,
                                double model_fitness_reference = 1.0);
// Whether a relocalisation candidate's track may be taken: tracked, and agreeing with the map where
// the map has a surface as well as tracked frames have lately, whatever its fitness. A candidate
// comes from a search, not from the last pose: a wrong one can slide a dominant plane (a desk) over
// itself and pair half the frame.
bool relocalisation_verified(const RegistrationResult& r, const RegistrationConfig& c,
                             double model_fitness_reference = 1.0);

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
class PhotometricTerm;

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
  // Coarse-to-fine for larger motions (tracking without a pose hint). Directions the view hardly
  // constrains keep a value ICP cannot supply: without `T_world_cam_held`, the initial pose's
  // below registration.degenerate_ratio (the batch's first round); with it (the tracking of a
  // moving camera), that pose's below registration.tracking_degenerate_ratio. The pipeline holds
  // them where the track starts: the motion model's prediction, or the last pose on a retry.
  RegistrationResult track(const MeasurementImage& m, const PointMap& map,
                           const Pose& T_world_cam_initial,
                           const std::optional<Pose>& T_world_cam_held = std::nullopt);
  // The MAP track of a moving camera: the depth's normal equations with the motion prior's, from
  // `T_world_cam_initial` (the prediction, or another start such as the last pose).
  RegistrationResult track(const MeasurementImage& m, const PointMap& map,
                           const Pose& T_world_cam_initial, const MotionPrior& prior);

  // The same against a view of the map made before, e.g. model() for the next frame.
  // Associations go through the view's camera, whatever the current estimate.
  RegistrationResult refine(const MeasurementImage& m, const SurfaceView& model,
                            const Pose& T_world_cam_initial);
  RegistrationResult track(const MeasurementImage& m, const SurfaceView& model,
                           const Pose& T_world_cam_initial,
                           const std::optional<Pose>& T_world_cam_held = std::nullopt);
  RegistrationResult track(const MeasurementImage& m, const SurfaceView& model,
                           const Pose& T_world_cam_initial, const MotionPrior& prior);
  // A track with no motion model to start it (a scan's first steps, the first after a loss): from
  // the last pose, which is as far from the camera as it has moved since, with its unconstrained
  // directions held there; registration.tracking_levels_without_motion levels, wider gates.
  RegistrationResult track_without_motion(const MeasurementImage& m, const PointMap& map,
                                          const Pose& T_world_cam_last);
  RegistrationResult track_without_motion(const MeasurementImage& m, const SurfaceView& model,
                                          const Pose& T_world_cam_last);

  // The model the last refine() or track() against the map rendered (empty before any).
  const SurfaceView& model() const { return view_; }

  // The photometric term of track() (registration.photometric_weight): the colour of the frame
  // about to be tracked, registered to its depth pixel for pixel (absent or of another size: no
  // term for this frame); once the frame is fused at T_world_cam, it becomes the reference the next
  // frames' intensities are compared with; forget_photometric_reference() for a new map.
  void set_frame_color(const ColorImage& color, const MeasurementImage& m);
  void keep_frame_as_photometric_reference(const MeasurementImage& m, const Pose& T_world_cam);
  void forget_photometric_reference();

 private:
  // Projects the map around the frame's measurements into the camera at T_world_cam, `downsample`
  // times coarser: view_, the consensus surface of the points within band_m behind the front-most,
  // for pairs up to max_corr_m.
  void render_model(const MeasurementImage& m, const PointMap& map, const Pose& T_world_cam,
                    double band_m, double max_corr_m, int downsample);
  // Where the directions ICP cannot determine are held: at `anchor` (nullptr: their current
  // value), below `degenerate_ratio` (see solve_step() in registration.cpp); or, with a motion
  // prior, none are held: the prior's normal equations join the depth's.
  struct Hold {
    const Pose* anchor;
    double degenerate_ratio;
    const MotionPrior* prior = nullptr;
  };
  Hold hold_for(const std::optional<Pose>& T_world_cam_held) const;
  // ICP against `model`, from `initial`, on every `subsample`-th pixel. Fewer than `min_pairs`
  // (at least 6) inlier pairs: not converged, the initial pose stays.
  RegistrationResult run(const MeasurementImage& m, const SurfaceView& model, const Pose& initial,
                         const Hold& hold, int subsample, int iterations, double max_corr_m,
                         size_t min_pairs, int photometric_level = -1);
  // Inlier pairs a level of coarse-to-fine needs (level 0: refine() and the finest level).
  size_t min_pairs(int level) const;
  // Renders the map for a track of `levels` levels: wide enough for the coarsest level's gate.
  void render_for_tracking(const MeasurementImage& m, const PointMap& map,
                           const Pose& T_world_cam_initial, int levels);
  // Coarse to fine over `levels` levels: every level halves the pixel step and the correspondence
  // gate and needs four times the pairs (registration.min_correspondences at the finest).
  RegistrationResult coarse_to_fine(const MeasurementImage& m, const SurfaceView& model,
                                    const Pose& T_world_cam_initial, const Hold& hold, int levels);
  int tracking_levels() const;
  int tracking_levels_without_motion() const;
  RegistrationConfig config_;
  std::unique_ptr<ModelProjection> projection_;
  std::unique_ptr<PhotometricTerm> photometric_;
  SurfaceView view_;  // the last rendered model
};

}  // namespace depthfuse
