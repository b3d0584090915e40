// A payload on one of our channels, decoded as each of our message types and, for frames, on
// into a depthfuse Frame: never a crash, never an allocation the message's bytes do not justify.
#include <cstddef>
#include <cstdint>

#include "depthfuse/color_frame_t.hpp"
#include "depthfuse/command_t.hpp"
#include "depthfuse/depth_frame_t.hpp"
#include "depthfuse/heartbeat_t.hpp"
#include "depthfuse/lcm/codec.hpp"
#include "depthfuse/lcm/frame_codec.hpp"
#include "depthfuse/map_delta_t.hpp"
#include "depthfuse/map_request_t.hpp"
#include "depthfuse/pose2_t.hpp"
#include "depthfuse/pose_t.hpp"
#include "depthfuse/status_t.hpp"

namespace {

template <typename Msg>
bool decode(const uint8_t* data, size_t size, Msg* msg) {
  return depthfuse::lcm::decode_message(data, size, msg) == depthfuse::lcm::DecodeResult::kOk;
}

}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  using namespace depthfuse;
  depth_frame_t depth;
  if (decode(data, size, &depth)) {
    Frame frame;
    (void)lcm::decode_depth_frame(depth, &frame);
  }
  color_frame_t color;
  if (decode(data, size, &color)) {
    ColorImage image;
    (void)lcm::decode_color_frame(color, &image);
  }
  pose_t pose;
  if (decode(data, size, &pose)) (void)lcm::pose_from_arrays(pose.position_m, pose.orientation_wxyz);
  pose2_t pose2;
  if (decode(data, size, &pose2))
    (void)lcm::pose_from_arrays(pose2.pose.position_m, pose2.pose.orientation_wxyz);
  command_t command;
  (void)decode(data, size, &command);
  heartbeat_t heartbeat;
  (void)decode(data, size, &heartbeat);
  status_t status;
  (void)decode(data, size, &status);
  depthfuse::map_delta_t map_delta;
  (void)decode(data, size, &map_delta);
  depthfuse::map_request_t map_request;
  (void)decode(data, size, &map_request);
  return 0;
}
