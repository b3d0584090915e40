// depthfuse_web_graph_sender: one loop closure's correction (graph_correction_t) on LCM, as the
// fusion daemon publishes it, for the page's test: every keyframe from --first-sequence on turns by
// --yaw-deg about z, then moves by (--dx, --dy, --dz) m. --spoil sends it with its translations'
// count wrong (a broken message the monitor must count and ignore).
#include <cmath>
#include <string>

#include "depthfuse/base/clock.hpp"
#include "depthfuse/base/log.hpp"
#include "depthfuse/daemon/startup.hpp"
#include "depthfuse/graph_correction_t.hpp"
#include "depthfuse/lcm/channels.hpp"

DF_LOG_CATEGORY(GraphSender)

namespace {

constexpr const char* kUsage =
    "usage: depthfuse_web_graph_sender [--lcm URL] [--key-file F] --scan-id ID [--sender NAME]\n"
    "                                  [--first-sequence N] [--dx M] [--dy M] [--dz M]\n"
    "                                  [--yaw-deg D] [--version N] [--spoil]\n";

}  // namespace

int main(int argc, char** argv) {
  namespace dd = depthfuse::daemon;
  return dd::run_main([&] {
    dd::Startup startup({"depthfuse_web_graph_sender", kUsage,
                         {"scan-id", "sender", "first-sequence", "dx", "dy", "dz", "yaw-deg", "version"},
                         {"spoil"}, {}, 0},
                        argc, argv);
    if (auto code = startup.exit_code()) return *code;
    const dd::Args& args = startup.args();
    if (args.get("scan-id").empty()) return startup.usage_error("--scan-id is required");
    long first_sequence = 0, version = 1;
    double t[3] = {0, 0, 0}, yaw_deg = 0;
    std::string error;
    if (!args.get_int("first-sequence", &first_sequence, &error) ||
        !args.get_int("version", &version, &error) || !args.get_double("dx", &t[0], &error) ||
        !args.get_double("dy", &t[1], &error) || !args.get_double("dz", &t[2], &error) ||
        !args.get_double("yaw-deg", &yaw_deg, &error))
      return startup.usage_error(error);
    auto lcm = startup.open_lcm();
    if (!lcm) return 1;

    depthfuse::graph_correction_t msg{};
    msg.protocol_version = depthfuse::graph_correction_t::PROTOCOL_VERSION;
    msg.utime = depthfuse::now_utime();
    msg.sender = args.get("sender", "fusion");
    msg.scan_id = args.get("scan-id");
    msg.version = static_cast<int32_t>(version);
    msg.loops = 1;
    msg.max_translation_m = std::sqrt(t[0] * t[0] + t[1] * t[1] + t[2] * t[2]);
    msg.num_keyframes = 1;
    msg.first_sequence = {first_sequence};
    msg.num_translations = args.has("spoil") ? 2 : 3;
    msg.motion_translation_m.assign(t, t + msg.num_translations);
    msg.num_rotations = 4;
    const double half_rad = yaw_deg * M_PI / 360;
    msg.motion_orientation_wxyz = {std::cos(half_rad), 0, 0, std::sin(half_rad)};
    if (auto st = lcm->publish_message(depthfuse::lcm::kGraphChannel, msg); !st.is_ok()) {
      DF_LOG(GraphSender, Error) << st.to_string();
      return 1;
    }
    return 0;
  });
}
