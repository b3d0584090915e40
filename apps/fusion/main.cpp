// depthfuse-fusion [--lcm URL] [--config FILE] [--name NAME] [--autostart [SCAN]] [--scan-dir DIR]
//                  [--queue N] [--scan-db FILE]
#include <cstdio>
#include <cstdlib>
#include <string>

#include "depthfuse/daemon/signals.hpp"
#include "fusion_daemon.hpp"

namespace {

void usage(FILE* out) {
  std::fprintf(out,
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
      "                    last checkpoint (default: SCAN_DIR/<scan>.dfscan per scan, likewise)\n");
}

}  // namespace

int main(int argc, char** argv) {
  std::string url, config_path, scan_dir, queue_text, scan_db;
  depthfuse::fusiond::DaemonOptions options;
  for (int i = 1; i < argc; ++i) {
    const std::string a = argv[i];
    auto need = [&](std::string* dst) {
      if (i + 1 >= argc) {
        std::fprintf(stderr, "depthfuse-fusion: %s needs a value\n", a.c_str());
        std::exit(2);
      }
      *dst = argv[++i];
    };
    if (a == "--help" || a == "-h") {
      usage(stdout);
      return 0;
    } else if (a == "--lcm") {
      need(&url);
    } else if (a == "--config") {
      need(&config_path);
    } else if (a == "--name") {
      need(&options.name);
    } else if (a == "--scan-dir") {
      need(&scan_dir);
    } else if (a == "--scan-db") {
      need(&scan_db);
    } else if (a == "--queue") {
      need(&queue_text);
    } else if (a == "--autostart") {
      options.autostart_scan = (i + 1 < argc && argv[i + 1][0] != '-') ? argv[++i] : "-";
    } else {
      std::fprintf(stderr, "depthfuse-fusion: unknown option '%s'\n", a.c_str());
      usage(stderr);
      return 2;
    }
  }
  auto& shutdown = depthfuse::daemon::ShutdownSignal::install();

  depthfuse::AppConfig config;
  if (!config_path.empty()) {
    auto loaded = depthfuse::load_app_config(config_path);
    if (!loaded) {
      std::fprintf(stderr, "depthfuse-fusion: %s\n", loaded.status().to_string().c_str());
      return 2;
    }
    config = std::move(loaded).value();
  }
  if (!url.empty()) config.lcm.url = url;
  if (!scan_dir.empty()) config.fusion.scan_dir = scan_dir;
  if (!queue_text.empty()) {
    char* end = nullptr;
    const long q = std::strtol(queue_text.c_str(), &end, 10);
    if (*end != '\0' || q < 1 || q > 10000) {
      std::fprintf(stderr, "depthfuse-fusion: --queue must be a number of frames in 1..10000\n");
      return 2;
    }
    config.fusion.queue_capacity_frames = static_cast<int>(q);
  }

  std::vector<std::string> warnings;
  auto opened = depthfuse::lcmio::LcmTransport::open(config.lcm.url, &warnings);
  for (const auto& w : warnings) std::fprintf(stderr, "depthfuse-fusion: warning: %s\n", w.c_str());
  if (!opened) {
    std::fprintf(stderr, "depthfuse-fusion: %s\n", opened.status().to_string().c_str());
    return 1;
  }
  depthfuse::fusiond::FusionDaemon daemon(config, options, std::move(opened).value(),
                                          depthfuse::fusiond::make_checkpoint_sink(config, scan_db));
  return daemon.run([&] { return shutdown.stop_requested(); });
}
