// Internal: the photometric term of tracking, as dense RGB-D odometry has it. A pixel of the frame
// is compared, by intensity, with what the last fused frame (the reference) saw where the pixel's
// point projects into it. The term constrains the pose where the geometry alone does not (a
// textured wall), and Registrar::track adds it to ICP's normal equations.
#pragma once

#include <vector>

#include <Eigen/Core>

#include "depthfuse/config.hpp"
#include "depthfuse/measurement.hpp"
#include "depthfuse/types.hpp"
#include "photometric_kernels.hpp"

namespace depthfuse {

// The term's sums for one Gauss-Newton step, in the twist of Registrar's ICP (rotation first,
// about a centre c, applied on the left in the world frame): J = [ (p_w - c) x g, g ].
struct PhotometricSums {
  Eigen::Matrix<double, 6, 6> H = Eigen::Matrix<double, 6, 6>::Zero();  // upper triangle
  Eigen::Matrix<double, 6, 1> b = Eigen::Matrix<double, 6, 1>::Zero();
  double sq_residual = 0;
  size_t pairs = 0;
  void merge(const PhotometricSums& o);
};

// The frame being tracked and the reference it is compared against. Without colour on either (or
// with registration.photometric_weight 0) it adds nothing.
class PhotometricTerm {
 public:
  explicit PhotometricTerm(const RegistrationConfig& config);

  // The frame about to be tracked: its colour, registered to the depth pixel for pixel. Colour
  // that is absent or of another size than `m` leaves the frame without the term.
  void set_frame(const ColorImage& color, const MeasurementImage& m);
  // The frame set last, fused at T_world_cam, becomes the reference of the frames after it.
  void keep_frame_as_reference(const MeasurementImage& m, const Pose& T_world_cam);
  // No reference (a new map).
  void clear();
  // Whether sums() has anything to add.
  bool ready() const;

  // The sums over every `step`-th pixel of m at the pose T_world_cam, on pyramid level `level`,
  // with the twist about `centre`. A pixel counts where its point projects into the reference and
  // lands within `gate_m` of the reference's depth there (not hidden from it).
  PhotometricSums sums(const MeasurementImage& m, const Pose& T_world_cam,
                       const Eigen::Vector3f& centre, int level, int step, float gate_m) const;
  // Adds weight * sums() to ICP's normal equations (H: upper triangle).
  void add_to(const MeasurementImage& m, const Pose& T_world_cam, const Eigen::Vector3f& centre,
              int level, int step, float gate_m, Eigen::Matrix<double, 6, 6>* H,
              Eigen::Matrix<double, 6, 1>* b) const;

 private:
  double weight_;
  int levels_;
  int threads_;
  std::vector<IntensityLevel> frame_, reference_;
  bool has_frame_ = false, has_reference_ = false;
  CameraIntrinsics reference_K_;
  std::vector<float> reference_depth_m_;  // the reference's measured depth, 0 where invalid
  Pose T_ref_world_ = Pose::Identity();
};

}  // namespace depthfuse
