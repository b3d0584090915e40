// One Config struct per module, units in the field names. Defaults are the Kinect V2 values and
// the paper's; config/depthfuse.toml documents each one and where it comes from.
#pragma once

#include <string>

namespace depthfuse {

// The paper's measurement covariance, aligned with the line of sight:
//   C = diag(lambda1 (beta_x z / sqrt 12)^2, lambda1 (beta_y z / sqrt 12)^2,
//            lambda2 (alpha2 z^2 + alpha1 z + alpha0)^2)
struct SensorModelConfig {
  double lambda1 = 12.0;           // lateral variance scale (ellipsoid size), dimensionless
  double lambda2 = 16.0;           // axial variance scale, dimensionless
  double beta_x_rad = 0.0;         // pixel width at 1 m; 0 = 1/fx of the frame's intrinsics
  double beta_y_rad = 0.0;         // pixel height at 1 m; 0 = 1/fy
  double alpha0_m = 1.5e-3;        // axial std dev polynomial, Fankhauser et al. 2015 (Kinect V2)
  double alpha1 = -0.5e-3;         // m per m
  double alpha2_per_m = 0.3e-3;    // m per m^2
  double min_depth_m = 0.5;        // Kinect V2 operating range
  double max_depth_m = 4.5;
  // The depth camera's rolling shutter, s (CameraIntrinsics::row_readout_s), for frames that do
  // not say: frames over LCM carry no readout time (depth_frame_t is frozen), so a rolling-shutter
  // sensor behind the capture daemon is described here. 0: a global shutter (the Kinect V2).
  double row_readout_s = 0.0;
};

// Pre-filter: drop a measurement whose distance to its k-th nearest neighbour in the back-projected
// depth map exceeds gamma * d_r(z), where d_r(z) is the same distance on a fronto-parallel plane.
struct PrefilterConfig {
  bool enabled = true;
  double gamma = 1.83;
  int neighbour_rank = 4;          // k
  int window_radius_px = 1;        // neighbours are searched in a (2r+1)^2 pixel window
};

struct FusionConfig {
  double chunk_size_m = 0.5;                 // edge of a map chunk (spatial hash cell)
  double visibility_range_fraction = 0.1;    // |s_e - s_n| < f * s_n, paper eq. (3)
  int candidate_radius_px = 1;               // existing points looked up in a (2r+1)^2 window
  int normal_radius_px = 2;                  // normals from central differences over this step
  int threads = 2;                           // 1 or 2: rendering and fusion split in two halves
  // A measurement that merges with no existing point is dropped as redundant, instead of being
  // added, when an existing point in its candidate window that has merged at least
  // redundancy_min_merges times lies inside the measurement's uncertainty ellipsoid scaled by
  // redundancy_gate (Mahalanobis distance <= gate). Gate 0 adds every such measurement, as the
  // paper does. Not part of the paper: without it the map grows with every revisit (see
  // config/depthfuse.toml).
  double redundancy_gate = 2.0;
  int redundancy_min_merges = 10;
  // After a loop closure the map follows the corrected poses (MapDeformation): besides the chunks
  // a frame sees, each frame brings at most about this many more points up to date (whole chunks,
  // nearest to the camera first).
  int deform_points_per_frame = 50000;
};

struct PostfilterConfig {
  bool enabled = true;             // remove points whose violations outnumber their merges
};

struct RegistrationConfig {
  bool enabled = true;
  int iterations = 10;                       // point-to-plane ICP iterations per depth map
  int subsample_px = 4;                      // use every n-th pixel in u and v
  double max_correspondence_m = 0.05;        // reject pairs farther apart than this
  double max_normal_angle_deg = 35.0;        // reject pairs whose normals disagree more
  double huber_delta_m = 0.005;              // robust loss scale
  int min_correspondences = 500;             // fewer: keep the initial pose, report failure
  // Directions of the pose whose information is below this fraction of the best-constrained one's
  // are left as they are (a view of one wall does not say where along the wall the camera is).
  double degenerate_ratio = 0.005;
  // The model surface at a pixel is the confidence-weighted mean of the points within this depth
  // band behind the nearest one (see ModelProjection::render_surface).
  double model_band_m = 0.05;
  // The same for tracking (track(): the first re-registration round, and live frames without a
  // pose hint). There the map is still as blurred as the initial poses are wrong, and a band
  // narrower than the blur keeps only its front layers: ICP then pulls every camera back.
  double tracking_model_band_m = 0.1;
  // The model is rendered this many times coarser than the depth camera (1 = full resolution).
  int model_downsample = 1;
  // The same for tracking. Each map point covers one model pixel, and the map keeps a surface at
  // the density of the view that first saw it: a camera walking towards a wall it saw from across
  // the room sees it through a model with holes, and finds pairs for a fraction of its samples.
  int tracking_model_downsample = 2;
  int threads = 2;                           // 1 or 2: model rendering and ICP in two halves
  // Tracking without a pose hint: coarse-to-fine levels (subsample 4, 2, 1 ...), iterations each.
  int tracking_levels = 3;
  // The same where no motion model predicts the pose yet (a scan's first steps, the first after a
  // loss): the track starts from the last pose, as far from the camera as it has moved since.
  int tracking_levels_without_motion = 5;
  int tracking_iterations_per_level = 10;
  // Tracking: weight of the photometric term (intensity of the frame against the last fused
  // frame's, 0..1) per squared point-to-plane metre; 0 = off, and off without colour.
  double photometric_weight = 0;
  // Tracking from a prediction whose result has an ICP fitness below this (or is lost) starts
  // again from the last refined pose; 0 = never.
  double tracking_retry_fitness = 0.5;
  // Tracking a moving camera (IncrementalReconstructor without a pose hint): directions below
  // this fraction of the best-constrained one's keep the value of the pose the track starts from
  // (see Registrar::track).
  double tracking_degenerate_ratio = 3e-3;
  // Tracking from the motion model's prediction is a MAP estimate (Registrar::track with a
  // MotionPrior): the depth's normal equations and a Gaussian prior at the prediction. false:
  // directions below tracking_degenerate_ratio are held at the prediction instead.
  bool motion_prior = true;
  // The depth's information is limited by the map's own error along a surface's normal, which does
  // not average out over the pairs (registration.cpp, data_scale).
  double model_error_m = 2e-4;
  // The prediction's uncertainty per frame period: the spread of the prediction errors of the last
  // frames that measured the motion themselves, in the camera frame, each axis at least these. A
  // frame after a gap scales it by the gap.
  double motion_prior_min_m = 1e-3;
  double motion_prior_min_deg = 0.1;
  // A frame tracked with the prior is uncertain when the depth had less than this share of the
  // estimate in some direction (RegistrationResult::data_share).
  double tracking_min_data_share = 0.5;
  // A tracked frame is lost (not fused) when its fitness is below this or its residual above that;
  // uncertain when its fitness is below tracking_retry_fitness, or the motion model decided a
  // direction (tracking_min_data_share; without a prior, its conditioning below
  // tracking_degenerate_ratio; classify_tracking()).
  double tracking_lost_fitness = 0.3;
  double tracking_lost_rmse_m = 0.02;
  // A frame whose fitness is below tracking_retry_fitness is lost, not uncertain, when fewer than
  // this share of its samples that fall on the model's surface have a pair (model_fitness), as a
  // fraction of what the last tracked frames scored (IncrementalReconstructor::
  // model_fitness_reference()). A relocalisation candidate must reach it whatever its fitness.
  double tracking_lost_model_fitness = 0.9;
  // Frame-by-frame registration (IncrementalReconstructor, the fusion daemon) may align a frame
  // to the model rendered for the frame before, instead of rendering the map again: for at most
  // live_model_reuse_frames frames in a row (1: never), and only while the initial pose is within
  // live_model_reuse_max_m and live_model_reuse_max_deg of where that model was rendered.
  int live_model_reuse_frames = 2;
  double live_model_reuse_max_m = 0.025;
  double live_model_reuse_max_deg = 2.0;
};

// Relocalisation of a camera whose tracking is lost (frames without pose hints; see Relocaliser in
// lib/src/relocaliser.hpp and config/depthfuse.toml [relocalisation]).
struct RelocalisationConfig {
  bool enabled = true;
  // A tracked frame becomes a keyframe when no keyframe is within both of these of its camera.
  double keyframe_spacing_m = 0.3;
  double keyframe_spacing_deg = 20.0;
  int max_keyframes = 32;
  // A keyframe's and a lost frame's points: the valid measurements averaged in cubes of voxel_m,
  // at most max_points of them; FPFH features over feature_radius_m.
  double voxel_m = 0.05;
  int max_points = 800;
  double feature_radius_m = 0.15;
  // Cost per lost frame: sample consensus against at most candidates_per_frame keyframes, on
  // every every_n_lost_frames-th lost frame in a row, sac_iterations draws each.
  int candidates_per_frame = 1;
  int every_n_lost_frames = 1;
  int sac_iterations = 300;
  // A sample-consensus pose is a candidate when this fraction of the frame's points lies within
  // sac_inlier_m of the keyframe's.
  double sac_inlier_m = 0.03;
  double sac_inlier_fraction = 0.3;
  // A pose found is believed only where the camera can have got to since the last frame fused:
  // within max_speed_m_s and max_turn_deg_s times the time since (and a tenth of a metre and ten
  // degrees for that frame's own error). A place that only looks like the camera's (a twin room,
  // a repeated shelf) is refused while the loss is short, rather than fused into.
  double max_speed_m_s = 1.5;
  double max_turn_deg_s = 180.0;
  // A place found is believed only when it is the one place that fits: up to ambiguity_rivals
  // other keyframes, the most alike first, are tried too, and if one of them is verified more than
  // ambiguity_m from the place found (also within reach), the frame could be in either (twin
  // rooms, a repeated shelf) and stays lost. 0 rivals: the first place verified is taken.
  int ambiguity_rivals = 3;
  double ambiguity_m = 0.5;
};

// Keyframes, the pose graph and loop closure (frames tracked without pose hints; see ScanGraph in
// scan_graph.hpp and config/depthfuse.toml [loop_closure]).
struct LoopClosureConfig {
  bool enabled = true;
  // A frame becomes a keyframe (a node of the pose graph) when the camera has moved this far, or
  // turned this much, since the last keyframe.
  double keyframe_spacing_m = 0.2;
  double keyframe_spacing_deg = 15.0;
  // A keyframe's points for verification: valid measurements averaged in cubes of voxel_m, at most
  // max_points of them, in its camera frame.
  double voxel_m = 0.03;
  int max_points = 1500;
  // While the keyframes' points take more than max_cloud_mib, searched keyframes give theirs up
  // (keeping their thumbnails), the oldest first, where an older keyframe whose camera lies within
  // both cloud_spacing_m and _deg of theirs kept its own: one cloud a place, so that the graph's
  // memory follows the space scanned, not the scan's length.
  double max_cloud_mib = 2.0;
  double cloud_spacing_m = 0.3;
  double cloud_spacing_deg = 20.0;
  // Candidates for a new keyframe: older keyframes at least min_keyframes_back keyframes and
  // min_path_m of camera path before it, whose camera lies within search_radius_m of it (or three
  // times the position uncertainty the odometry has accumulated between them, if more) and looks
  // within max_view_angle_deg of its direction; at most candidates_per_keyframe, nearest first.
  int min_keyframes_back = 10;
  double min_path_m = 1.0;
  double search_radius_m = 0.5;
  double max_view_angle_deg = 45.0;
  int candidates_per_keyframe = 2;
  // The place search (the relocaliser's FPFH and sample consensus, relocalisation.*) on every
  // place_search_every_n_keyframes-th keyframe: the older keyframe whose depth thumbnail is most
  // alike; 0 = never.
  int place_search_every_n_keyframes = 4;
  // A candidate is believed when ICP of the keyframe's points against the candidate's pairs this
  // share of them within max_correspondence_m (the points are cubes' means: nearest neighbours of
  // two views lie up to a cube apart) with residual at most max_rmse_m, and its correction
  // of the graph is within the odometry's uncertainty (chi-square below gate_chi2, six degrees of
  // freedom, the odometry's covariance inflated by gate_inflation squared).
  double min_overlap = 0.4;
  double max_correspondence_m = 0.05;
  double max_rmse_m = 0.008;
  double gate_chi2 = 22.5;
  double gate_inflation = 3.0;
  // The map's error in a loop edge's information, as registration.model_error_m in the odometry's.
  double model_error_m = 1e-3;
  // The optimiser (optimise_pose_graph): its robust loss scale and rejection threshold for loops.
  double loop_loss_scale = 4.0;
  double loop_chi2_reject = 16.8;
  // It moves the newest optimise_window_keyframes keyframes only; the older ones hold them (and
  // their loops) in place. A solve then costs the same however long the scan; a loop longer than
  // the window has its correction spread over the window's part of it. 0: the whole graph.
  int optimise_window_keyframes = 150;
};

enum class Method { kKyostila13, kYlimaki17, kFull };
const char* to_string(Method m);
bool parse_method(const std::string& text, Method* out);

struct PipelineConfig {
  Method method = Method::kFull;
  int outer_iterations = 6;                  // fuse, re-register, fuse again: the paper uses 6
  double converged_translation_m = 2e-4;     // stop early when no pose moves more than this
  double converged_rotation_deg = 0.01;      // ... and no rotation changes more than this
};

struct ReconstructionConfig {
  SensorModelConfig sensor;
  PrefilterConfig prefilter;
  FusionConfig fusion;
  PostfilterConfig postfilter;
  RegistrationConfig registration;
  RelocalisationConfig relocalisation;
  LoopClosureConfig loop_closure;
  PipelineConfig pipeline;

  // The stages the method switch turns on: kyostila13 = fusion only, ylimaki17 = + pre/post
  // filters, full = + re-registration.
  ReconstructionConfig with_method(Method m) const;
};

}  // namespace depthfuse
