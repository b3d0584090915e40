// depthfuse_web_map_feeder: map deltas on LCM at a chosen byte rate, as a fusion daemon scanning
// fast would send them, for the web server's tests: the monitor forwards them to its pages, so a
// page that does not read falls behind within a second, without running the fusion pipeline.
// The chunks cycle over a fixed set of keys, so the monitor's copy of the map stays small.
#include <algorithm>
#include <chrono>
#include <random>
#include <string>
#include <thread>

#include "depthfuse/base/clock.hpp"
#include "depthfuse/base/log.hpp"
#include "depthfuse/daemon/signals.hpp"
#include "depthfuse/daemon/startup.hpp"
#include "depthfuse/lcm/channels.hpp"
#include "depthfuse/map_delta_t.hpp"

DF_LOG_CATEGORY(MapFeeder)

namespace {

constexpr const char* kUsage =
    "usage: depthfuse_web_map_feeder [--lcm URL] [--bytes-per-s B] [--seconds S] [--keys N]\n"
    "  --bytes-per-s B  map deltas' bytes per second on LCM (default 2000000)\n"
    "  --seconds S      then stop (default 10)\n"
    "  --keys N         distinct chunks, cycled (default 32)\n";

constexpr int kPointsPerChunk = 2000;
constexpr double kRateHz = 10.0;
constexpr size_t kEncodedBytesPerPoint = 11;  // int16 xyz, int8 normal, int16 uncertainty

depthfuse::map_chunk_t make_chunk(int index, std::mt19937* rng) {
  std::uniform_int_distribution<int> coord(-30000, 30000), unc(10, 3000);
  depthfuse::map_chunk_t c{};
  c.key[0] = index % 8;
  c.key[1] = (index / 8) % 8;
  c.key[2] = index / 64;
  c.num_points = c.map_points = kPointsPerChunk;
  c.num_coords = 3 * kPointsPerChunk;
  c.coverage = 0.5f;
  c.position.resize(c.num_coords);
  c.normal.assign(c.num_coords, 0);
  c.uncertainty.resize(c.num_points);
  for (auto& p : c.position) p = static_cast<int16_t>(coord(*rng));
  for (auto& u : c.uncertainty) u = static_cast<int16_t>(unc(*rng));
  return c;
}

}  // namespace

int main(int argc, char** argv) {
  namespace dd = depthfuse::daemon;
  return dd::run_main([&] {
    dd::Startup startup({"depthfuse_web_map_feeder", kUsage, {"bytes-per-s", "seconds", "keys"}, {}, {}, 0},
                        argc, argv);
    if (auto code = startup.exit_code()) return *code;
    double bytes_per_s = 2e6, seconds = 10;
    long keys = 32;
    std::string error;
    if (!startup.args().get_double("bytes-per-s", &bytes_per_s, &error, dd::positive()) ||
        !startup.args().get_double("seconds", &seconds, &error, dd::positive()) ||
        !startup.args().get_int("keys", &keys, &error, dd::closed(1, 512)))
      return startup.usage_error(error);
    auto& shutdown = dd::ShutdownSignal::install();
    auto lcm = startup.open_lcm();
    if (!lcm) return 1;

    std::mt19937 rng(1);
    const size_t chunk_bytes = kPointsPerChunk * kEncodedBytesPerPoint;
    const int per_message = std::max(1, static_cast<int>(bytes_per_s / kRateHz / chunk_bytes));
    depthfuse::map_delta_t msg{};
    msg.protocol_version = depthfuse::map_delta_t::PROTOCOL_VERSION;
    msg.sender = "fusion";
    msg.scan_id = "web-test-feed";
    msg.kind = depthfuse::map_delta_t::KIND_DELTA;
    msg.state = 2;  // running
    msg.has_pose = true;
    msg.orientation_wxyz[0] = 1;
    msg.chunk_size_m = 0.5f;
    msg.cell_size_m = 0.015f;
    msg.position_unit_m = 0.25f / 30000;
    msg.uncertainty_unit_m = 1e-6f;
    msg.target_uncertainty_m = 0.002f;
    const auto period = std::chrono::duration<double>(1.0 / kRateHz);
    const auto start = std::chrono::steady_clock::now();
    int next_key = 0, sent = 0;
    for (auto t = start; t - start < std::chrono::duration<double>(seconds) && !shutdown.stop_requested();
         t += std::chrono::duration_cast<std::chrono::steady_clock::duration>(period)) {
      msg.chunks.clear();
      for (int i = 0; i < per_message; ++i, next_key = (next_key + 1) % keys)
        msg.chunks.push_back(make_chunk(next_key, &rng));
      msg.num_chunks = static_cast<int32_t>(msg.chunks.size());
      msg.utime = depthfuse::now_utime();
      ++msg.sequence;
      msg.map_points = static_cast<int64_t>(keys) * kPointsPerChunk;
      if (auto st = lcm->publish_message(depthfuse::lcm::kMapChannel, msg); !st.is_ok())
        DF_LOG(MapFeeder, Warning) << st.to_string();
      ++sent;
      std::this_thread::sleep_until(t + period);
    }
    DF_LOG(MapFeeder, Info) << sent << " deltas of " << per_message << " chunks sent";
    return 0;
  });
}
