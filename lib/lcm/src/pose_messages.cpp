#include "depthfuse/lcm/pose_messages.hpp"

#include "depthfuse/lcm/frame_codec.hpp"

namespace depthfuse::lcm {

pose2_t make_pose2(const Frame& frame, const FrameReport& report, const Pose& T_world_cam_last_placed,
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
  pose_to_arrays(report.placed() ? report.T_world_cam : T_world_cam_last_placed, pose.position_m,
                 pose.orientation_wxyz);
  if (report.fused()) {
    pose.measurements = static_cast<int32_t>(report.fusion.measurements);
    pose.merged = static_cast<int32_t>(report.fusion.merged);
    pose.added = static_cast<int32_t>(report.fusion.added);
    pose.fusion_ms = static_cast<float>(report.fusion_ms);
  }
  return pose2;
}

graph_correction_t make_graph_correction(const AppliedCorrection& c,
                                         const std::function<int64_t(uint32_t)>& sequence_of,
                                         const std::string& sender, const std::string& scan_id,
                                         int64_t utime) {
  graph_correction_t m{};
  m.protocol_version = graph_correction_t::PROTOCOL_VERSION;
  m.utime = utime;
  m.sender = sender;
  m.scan_id = scan_id;
  m.version = static_cast<int32_t>(c.version);
  m.loops = static_cast<int32_t>(c.loops);
  m.max_translation_m = c.max_translation_m;
  m.num_keyframes = static_cast<int32_t>(c.motion.size());
  m.num_translations = 3 * m.num_keyframes;
  m.num_rotations = 4 * m.num_keyframes;
  m.first_sequence.reserve(c.motion.size());
  m.motion_translation_m.resize(static_cast<size_t>(m.num_translations));
  m.motion_orientation_wxyz.resize(static_cast<size_t>(m.num_rotations));
  for (size_t k = 0; k < c.motion.size(); ++k) {
    m.first_sequence.push_back(sequence_of(c.first_frame_id[k]));
    pose_to_arrays(c.motion[k], &m.motion_translation_m[3 * k], &m.motion_orientation_wxyz[4 * k]);
  }
  return m;
}

}  // namespace depthfuse::lcm
