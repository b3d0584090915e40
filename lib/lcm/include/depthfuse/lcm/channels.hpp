// The LCM channels of the appliance. docs/protocol.md lists them with their types.
#pragma once

namespace depthfuse::lcm {

inline constexpr const char* kDepthChannel = "DEPTHFUSE_DEPTH";          // depth_frame_t
inline constexpr const char* kColorChannel = "DEPTHFUSE_COLOR";          // color_frame_t
inline constexpr const char* kPoseChannel = "DEPTHFUSE_POSE";            // pose_t
inline constexpr const char* kPose2Channel = "DEPTHFUSE_POSE2";          // pose2_t
inline constexpr const char* kHeartbeatChannel = "DEPTHFUSE_HEARTBEAT";  // heartbeat_t
inline constexpr const char* kStatusChannel = "DEPTHFUSE_STATUS";        // status_t
inline constexpr const char* kCommandChannel = "DEPTHFUSE_COMMAND";      // command_t
inline constexpr const char* kMapChannel = "DEPTHFUSE_MAP";              // map_delta_t
inline constexpr const char* kMapRequestChannel = "DEPTHFUSE_MAP_REQUEST";  // map_request_t
inline constexpr const char* kGraphChannel = "DEPTHFUSE_GRAPH";          // graph_correction_t

// The protocol version every message of this build carries (the PROTOCOL_VERSION constants of the
// message types agree with it; a test checks that).
inline constexpr int kProtocolVersion = 1;

}  // namespace depthfuse::lcm
