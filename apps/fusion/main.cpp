// depthfuse-fusion: the fusion daemon (FusionDaemon) started from the command line.
#include <string>

#include "depthfuse/base/log.hpp"
#include "depthfuse/daemon/signals.hpp"
#include "depthfuse/daemon/startup.hpp"
#include "fusion_daemon.hpp"
#include "memory_budget.hpp"

DF_LOG_CATEGORY(Fusion)

namespace {

constexpr const char* kUsage =
    "usage: depthfuse-fusion [--lcm URL] [--config FILE] [--name NAME] [--autostart [SCAN]]\n"
    "                        [--scan-dir DIR] [--queue N] [--scan-db FILE]\n"
    "Fuses the depth frames on LCM into a point cloud, frame by frame, and publishes the refined\n"
    "poses. Scans are started and stopped with 'depthfuse scan start|stop|...'.\n"
    "  --config FILE     the appliance's TOML (default: built-in defaults)\n"
    "  --lcm URL         overrides lcm.url\n"
    "  --name NAME       heartbeat name and command target (default: fusion)\n"
    "  --autostart SCAN  start scan SCAN at once ('-' or nothing: a name from the time)\n"
    "  --scan-dir DIR    overrides fusion_daemon.scan_dir (PLY and trajectory on stop)\n"
    "  --queue N         overrides fusion_daemon.queue_capacity_frames\n"
    "  --scan-db FILE    the first scan's SQLite scan file; an existing one is resumed from its\n"
    "                    last checkpoint (default: SCAN_DIR/<scan>.dfscan per scan, likewise)\n";

}  // namespace

int main(int argc, char** argv) {
  namespace dd = depthfuse::daemon;
  namespace fusiond = depthfuse::fusiond;
  return dd::run_main([&] {
    dd::Startup startup(
        {"depthfuse-fusion", kUsage, {"name", "scan-dir", "queue", "scan-db"}, {}, {"autostart"}, 0},
        argc, argv);
    if (auto code = startup.exit_code()) return *code;
    const dd::Args& args = startup.args();
    depthfuse::AppConfig& config = startup.config();
    fusiond::DaemonOptions options;
    options.name = args.get("name", options.name);
    if (args.has("autostart")) {  // with no scan name: one from the time
      options.autostart_scan = args.get("autostart");
      if (options.autostart_scan.empty()) options.autostart_scan = "-";
    }
    if (!args.get("scan-dir").empty()) config.fusion.scan_dir = args.get("scan-dir");
    long queue = config.fusion.queue_capacity_frames;
    std::string error;
    if (!args.get_int("queue", &queue, &error, dd::closed(1, 10000)))
      return startup.usage_error(error + " (frames)");
    config.fusion.queue_capacity_frames = static_cast<int>(queue);
    // A config error, like the ones the config's own checks find. Before any thread starts: see
    // reserve_heap().
    if (auto st = fusiond::MemoryBudget::of(config).check_and_reserve(); !st.is_ok()) {
      DF_LOG(Fusion, Error) << st.message();
      return 2;
    }

    auto& shutdown = dd::ShutdownSignal::install();
    auto lcm = startup.open_lcm();
    if (!lcm) return 1;
    fusiond::FusionDaemon daemon(config, options, std::move(lcm),
                                 fusiond::make_checkpoint_sink(config, args.get("scan-db")));
    return daemon.run([&] { return shutdown.stop_requested(); });
  });
}
