#include "depthfuse/lcm/pose_messages.hpp"

#include "depthfuse/lcm/frame_codec.hpp"

namespace depthfuse::lcm {

pose2_t make_pose2(const Frame& frame, const FrameReport& report, const Pose& T_world_cam_last_fused,
                   const FramePublication& publication) {
  pose2_t pose2{};
  pose2.protocol_version = pose2_t::PROTOCOL_VERSION;
  pose2.tracking = static_cast<int8_t>(report.tracking);
  pose2.fused = report.fused();
  pose2.icp_conditioning = report.registration.conditioning;
  pose_t& pose = pose2.pose;
  pose.protocol_version = pose_t::PROTOCOL_VERSION;
  pose.utime = frame.utime;
  pose.sequence = frame.sequence;
  pose.frame_publish_utime = publication.frame_publish_utime;
  pose.publish_utime = publication.publish_utime;
  pose.scan_id = publication.scan_id;
  pose.registered = report.registered;
  pose.icp_fitness = report.registration.fitness;
  pose.icp_rmse_m = report.registration.rmse_m;
  pose.icp_correspondences = static_cast<int32_t>(report.registration.correspondences);
  pose.icp_iterations = report.registration.iterations;
  pose.prefiltered = static_cast<int32_t>(report.prefiltered);
  pose.prefilter_ms = static_cast<float>(report.prefilter_ms);
  pose.registration_ms = static_cast<float>(report.registration_ms);
  pose.map_points = publication.map_points;
  pose_to_arrays(report.fused() ? report.T_world_cam : T_world_cam_last_fused, pose.position_m,
                 pose.orientation_wxyz);
  if (report.fused()) {
    pose.measurements = static_cast<int32_t>(report.fusion.measurements);
    pose.merged = static_cast<int32_t>(report.fusion.merged);
    pose.added = static_cast<int32_t>(report.fusion.added);
    pose.fusion_ms = static_cast<float>(report.fusion_ms);
  }
  return pose2;
}

}  // namespace depthfuse::lcm
