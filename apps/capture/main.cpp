// depthfuse-capture: reads a FrameSource (Kinect V2, TUM folder, synthetic scene, LCM log) and
// publishes its depth (and colour) frames on LCM with sequence numbers, plus a heartbeat at 1 Hz.
// Obeys pause/resume/stop/start addressed to it ("capture" by default). Clean exit on SIGINT/SIGTERM.
// A live source that is unavailable for now (no Kinect plugged in, USB not accessible yet) is waited
// for, never a reason to exit; with a Kinect the heartbeat carries its device state.
#include "capture_daemon.hpp"
#include "depthfuse/base/log.hpp"
#include "depthfuse/daemon/startup.hpp"

DF_LOG_CATEGORY(Capture)

namespace {

constexpr const char* kUsage =
    "usage: depthfuse-capture [--source SPEC] [--rate HZ|max|recorded] [--loop] [--lcm URL]\n"
    R"(                         [--config FILE] [--name NAME] [--color zstd|raw|jpeg|none]
                         [--depth-encoding zstd|raw] [--depth-unit M] [--linger]
  --source SPEC   tum:<folder> | synthetic:<SCENE>[?frames=N&...&hints=0] | kinect2[:serial]
                  | kinect2sim:<SCENE>[?frames=N&...] | lcmlog:<file>; SCENE: corner, room,
                  rooms, furnished or plain
                  (default: the config's capture.source)
  --rate          frames per second; 'max' as fast as possible; 'recorded' the pace of the
                  frame timestamps (default for lcmlog). Default: the source's own rate,
                  else the config's capture.rate_hz
  --loop          rewind a finite source at its end
  --lcm URL       LCM URL (default: the config's lcm.url)
  --name NAME     heartbeat name and command target (default: capture)
  --depth-unit M  metres per depth count on the wire (default 0.001; 0.0002 keeps TUM's
                  1/5000 m exactly)
  --linger        keep running (heartbeat state 'finished') when a finite source ends
)";

}  // namespace

int main(int argc, char** argv) {
  namespace capture = depthfuse::capture;
  namespace dd = depthfuse::daemon;
  return dd::run_main([&] {
    dd::Startup startup(
        {"depthfuse-capture", kUsage, capture::kCaptureOptionNames, capture::kCaptureFlagNames, {}, 0},
        argc, argv);
    if (auto code = startup.exit_code()) return *code;
    auto options = capture::capture_options(startup.args(), startup.config());
    if (!options) {
      DF_LOG(Capture, Error) << options.status().message();
      return 2;
    }
    auto& shutdown = dd::ShutdownSignal::install();
    auto lcm = startup.open_lcm();
    if (!lcm) return 1;
    capture::CaptureDaemon daemon(startup.config(), std::move(options).value(), std::move(lcm));
    return daemon.run(shutdown);
  });
}
