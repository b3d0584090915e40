// depthfuse-monitor: the monitor daemon (MonitorDaemon) started from the command line.
#include <string>

#include "depthfuse/base/log.hpp"
#include "depthfuse/daemon/signals.hpp"
#include "depthfuse/daemon/startup.hpp"
#include "monitor_daemon.hpp"

DF_LOG_CATEGORY(MonitorMain)

namespace {

constexpr const char* kUsage =
    "usage: depthfuse-monitor [--lcm URL] [--config FILE] [--stale-after S] [--rate HZ]\n"
    "                         [--http ADDR:PORT] [--web-root DIR] [--allow-origin LIST]\n"
    "  --stale-after S  a daemon without a heartbeat for S seconds is reported stale\n"
    "                   (default: the config's monitor.stale_after_s)\n"
    "  --rate HZ        status messages per second (default: monitor.publish_rate_hz)\n"
    "  --http ADDR:PORT serve the operator's page there (default: monitor.http; empty = off);\n"
    "                   loopback only unless monitor.http_allow_remote (which needs the rig key);\n"
    "                   with a rig key, the page's commands must be signed with it; PORT 0 takes\n"
    "                   a free one\n"
    "  --web-root DIR   the page's files (default: monitor.web_root, else the installed ones)\n"
    "  --allow-origin LIST  origins besides the page's own whose requests are taken, comma-\n"
    "                   separated, e.g. https://rig.example for a TLS proxy that changes the Host\n";

}  // namespace

int main(int argc, char** argv) {
  namespace dd = depthfuse::daemon;
  namespace monitor = depthfuse::monitor;
  return dd::run_main([&] {
    dd::Startup startup(
        {"depthfuse-monitor", kUsage, {"stale-after", "rate", "http", "web-root", "allow-origin"}, {}, {}, 0}, argc,
        argv);
    if (auto code = startup.exit_code()) return *code;
    monitor::MonitorOptions options;
    options.stale_after_s = startup.config().monitor.stale_after_s;
    options.rate_hz = startup.config().monitor.publish_rate_hz;
    std::string error;
    if (!startup.args().get_double("stale-after", &options.stale_after_s, &error, dd::positive()) ||
        !startup.args().get_double("rate", &options.rate_hz, &error, dd::positive()))
      return startup.usage_error(error);
    auto& shutdown = dd::ShutdownSignal::install();
    auto lcm = startup.open_lcm();
    if (!lcm) return 1;
    monitor::MonitorDaemon daemon(options, std::move(lcm));
    const auto& mc = startup.config().monitor;
    monitor::WebServerOptions page;
    page.listen = startup.args().get("http", mc.http);
    page.allow_remote = mc.http_allow_remote;
    page.web_root = startup.args().get("web-root", mc.web_root.empty() ? dd::installed_data_dir("web") : mc.web_root);
    auto origins = monitor::parse_origins(startup.args().get("allow-origin"));
    if (!origins) return startup.usage_error("--allow-origin: " + origins.status().message());
    page.allowed_origins = *origins;
    if (!page.listen.empty()) {
      // The key that signs the monitor's LCM messages also checks the page's commands.
      auto key = startup.rig_key();
      if (!key) {
        DF_LOG(MonitorMain, Error) << key.status().to_string();
        return 1;
      }
      page.key = *key;
      page.max_skew_us = static_cast<int64_t>(startup.config().lcm.max_clock_skew_s * 1e6);
      if (auto st = daemon.serve_page(page); !st.is_ok()) {
        DF_LOG(MonitorMain, Error) << st.to_string();
        return 1;
      }
    }
    return daemon.run(shutdown);
  });
}
