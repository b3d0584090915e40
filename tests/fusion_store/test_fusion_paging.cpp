// Bounded memory through the fusion daemon, end to end: one depthfuse-capture (synthetic rooms
// walk, one loop through the 16 rooms and on into the first ones again) feeds two depthfuse-fusion
// processes on the same LCM at once, one with a tiny fusion_daemon.memory_budget_mib, one with a
// budget it never reaches. The bounded daemon must evict chunks while it walks away and load them
// back when it returns, keep far less resident than the unbounded one, and still end with the same
// scan file: every chunk bit-identical, the same poses, the same exported PLY.
#include <cstring>

#include "depthfuse/daemon/heartbeat.hpp"
#include "depthfuse/heartbeat_t.hpp"
#include "depthfuse/lcm/channels.hpp"
#include "depthfuse/lcm/codec.hpp"
#include "depthfuse/store/scan_store.hpp"
#include "lcm_test_util.hpp"
#include "memory_budget.hpp"
#include "store_test_util.hpp"

namespace depthfuse::testing {
namespace {

using std::chrono::milliseconds;
using std::chrono::seconds;

// The walk is 0.5 m/s along a ~71.4 m tour, so at 1 frame per scan second one loop is ~143
// frames; 160 frames go round once and back through the first rooms, which were evicted by then.
constexpr int kFrames = 160;
// A queue longer than the scan: neither daemon drops a frame however far behind it falls, so both
// fuse exactly the same frames.
constexpr int kQueue = kFrames + 50;
constexpr const char* kSource = "synthetic:rooms?frames=160&rate_hz=1&seed=7";

struct DaemonRun {
  std::string name;                      // heartbeat name
  std::string dir, config, db;
  std::unique_ptr<Process> process;
  std::optional<depthfuse::heartbeat_t> last_hb;
  double max_resident_mib = 0;
};

class FusionPaging : public ::testing::Test {
 protected:
  void SetUp() override {
    url_ = test_url();
    require_multicast_route(url_);
  }
  // The map gets map_budget_mib: the budget adds the per-frame work of the synthetic frames and
  // the test's queue.
  void configure(DaemonRun* run, const std::string& name, double map_budget_mib) {
    run->name = name;
    run->dir = dir_.file(name);
    std::filesystem::create_directories(run->dir);
    run->config = run->dir + "/depthfuse.toml";
    run->db = run->dir + "/scan.db";
    AppConfig config;
    config.fusion.max_frame_width = 512;
    config.fusion.max_frame_height = 424;
    config.fusion.queue_capacity_frames = kQueue;
    const double budget_mib = map_budget_mib + fusiond::MemoryBudget::of(config).frame_work_mib();
    std::ofstream(run->config) << std::fixed << "[fusion_daemon]\nmemory_budget_mib = " << budget_mib
                               << "\nmax_frame_width = 512\nmax_frame_height = 424"
                               << "\ncheckpoint_interval_s = 3.0\nkeyframe_every_n_frames = 20\n"
                                  "heartbeat_rate_hz = 5.0\nscan_dir = \""
                               << run->dir << "/scans\"\n";
  }
  void start(DaemonRun* run) {
    run->process = std::make_unique<Process>(
        std::vector<std::string>{bin("depthfuse-fusion"), "--key-file", "", "--config", run->config, "--lcm", url_,
                                 "--name", run->name, "--scan-db", run->db, "--queue",
                                 std::to_string(kQueue), "--autostart", "paging"},
        run->dir + "/fusion.log");
  }
  std::string url_;
  store::test::TempDir dir_{"fusion-paging"};
};

std::string read_bytes(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  std::stringstream ss;
  ss << in.rdbuf();
  return ss.str();
}

bool same_pose(const Pose& a, const Pose& b) {
  return std::memcmp(a.matrix().data(), b.matrix().data(), sizeof(double) * 16) == 0;
}

TEST_F(FusionPaging, TinyBudgetEvictsReloadsAndGivesTheUnboundedCloud) {
  DaemonRun bounded, unbounded;
  configure(&bounded, "fusion-bounded", 4.0);
  configure(&unbounded, "fusion-unbounded", 1.0e6);

  std::mutex mutex;
  Listener listener(url_);
  ASSERT_TRUE(listener.error().empty()) << listener.error();
  listener.subscribe(lcm::kHeartbeatChannel, [&](const std::string&, const uint8_t* d, size_t n,
                                                   int64_t) {
    depthfuse::heartbeat_t hb;
    if (lcm::decode_message(d, n, &hb) != lcm::DecodeResult::kOk) return;
    std::lock_guard<std::mutex> lock(mutex);
    for (DaemonRun* run : {&bounded, &unbounded}) {
      if (hb.name != run->name) continue;
      run->last_hb = hb;
      run->max_resident_mib = std::max(run->max_resident_mib, daemon::counter_value(hb, "resident_mib"));
    }
  });
  listener.start();
  auto frames_out = [&](DaemonRun& run) -> int64_t {
    std::lock_guard<std::mutex> lock(mutex);
    return run.last_hb ? run.last_hb->frames_out : -1;
  };

  start(&bounded);
  start(&unbounded);
  // Both scans running before the first frame is sent.
  auto running = [&](DaemonRun& run) {
    std::lock_guard<std::mutex> lock(mutex);
    return run.last_hb && run.last_hb->state == depthfuse::heartbeat_t::STATE_RUNNING;
  };
  ASSERT_TRUE(eventually([&] { return running(bounded) && running(unbounded); }, seconds(20)))
      << bounded.process->log() << unbounded.process->log();
  Process capture({bin("depthfuse-capture"), "--key-file", "", "--source", kSource, "--lcm", url_, "--color", "none",
                   "--rate", "6"},
                  dir_.file("capture.log"));
  ASSERT_TRUE(capture.wait(seconds(120))) << capture.log();
  ASSERT_EQ(capture.exit_code(), 0) << capture.log();
  // Both daemons work through their queues.
  EXPECT_TRUE(eventually([&] { return frames_out(bounded) >= kFrames && frames_out(unbounded) >= kFrames; },
                         seconds(150)))
      << "fused " << frames_out(bounded) << " and " << frames_out(unbounded) << " of " << kFrames
      << " frames\n" << bounded.process->log() << unbounded.process->log();
  std::this_thread::sleep_for(milliseconds(500));  // a heartbeat after the last frame
  listener.stop();
  for (DaemonRun* run : {&bounded, &unbounded}) {
    run->process->signal(SIGTERM);
    ASSERT_TRUE(run->process->wait(seconds(60))) << run->process->log();
    EXPECT_EQ(run->process->exit_code(), 0) << run->process->log();
  }

  // The budget was applied: chunks went out and came back, and far less stayed resident.
  ASSERT_TRUE(bounded.last_hb && unbounded.last_hb);
  const double evicted = daemon::counter_value(*bounded.last_hb, "chunks_evicted_total");
  const double loaded = daemon::counter_value(*bounded.last_hb, "chunks_loaded_total");
  EXPECT_GT(evicted, 100) << "the bounded daemon hardly evicted";
  EXPECT_GT(loaded, 20) << "the walk's return loaded nothing back";
  EXPECT_EQ(daemon::counter_value(*unbounded.last_hb, "chunks_evicted_total"), 0);
  EXPECT_LT(bounded.max_resident_mib, 0.5 * unbounded.max_resident_mib);
  EXPECT_NEAR(daemon::counter_value(*bounded.last_hb, "budget_map_mib"), 4.0, 1e-3);
  EXPECT_EQ(bounded.last_hb->frames_dropped, 0);
  EXPECT_EQ(unbounded.last_hb->frames_dropped, 0);
  std::printf("bounded: evicted %.0f chunks, loaded %.0f back, resident at most %.1f MiB; "
              "unbounded: resident at most %.1f MiB\n",
              evicted, loaded, bounded.max_resident_mib, unbounded.max_resident_mib);

  // The same scan: poses, then every chunk bit for bit.
  auto a = store::ScanStore::open(unbounded.db, store::OpenMode::kReadOnly);
  auto b = store::ScanStore::open(bounded.db, store::OpenMode::kReadOnly);
  ASSERT_TRUE(a.is_ok()) << a.status().to_string();
  ASSERT_TRUE(b.is_ok()) << b.status().to_string();
  auto poses_a = (*a)->read_poses();
  auto poses_b = (*b)->read_poses();
  ASSERT_TRUE(poses_a.is_ok() && poses_b.is_ok());
  ASSERT_EQ(poses_a->size(), static_cast<size_t>(kFrames));
  ASSERT_EQ(poses_b->size(), static_cast<size_t>(kFrames));
  for (size_t i = 0; i < poses_a->size(); ++i) {
    ASSERT_EQ((*poses_a)[i].utime, (*poses_b)[i].utime) << i;
    EXPECT_TRUE(same_pose((*poses_a)[i].T_world_cam, (*poses_b)[i].T_world_cam)) << "frame " << i;
  }
  auto chunks_a = (*a)->list_chunks();
  auto chunks_b = (*b)->list_chunks();
  ASSERT_TRUE(chunks_a.is_ok() && chunks_b.is_ok());
  ASSERT_EQ(chunks_a->size(), chunks_b->size());
  size_t points = 0, differ = 0;
  for (size_t i = 0; i < chunks_a->size(); ++i) {
    const ChunkKey& k = (*chunks_a)[i].key;
    ASSERT_EQ(k, (*chunks_b)[i].key) << i;
    auto ca = (*a)->read_chunk(k);
    auto cb = (*b)->read_chunk(k);
    ASSERT_TRUE(ca.is_ok()) << ca.status().to_string();
    ASSERT_TRUE(cb.is_ok()) << cb.status().to_string();
    points += ca->chunk.points().size();
    if (!(ca->chunk.points() == cb->chunk.points())) {
      ++differ;
      ADD_FAILURE() << "chunk " << store::to_string(k) << ": " << ca->chunk.points().size() << " points unbounded, "
                    << cb->chunk.points().size() << " bounded";
      if (differ > 5) break;
    }
  }
  EXPECT_GT(points, 100000u);
  // And the clouds the daemons exported on stop (streamed from their files) are the same bytes.
  const std::string ply_a = read_bytes(unbounded.dir + "/scans/paging.ply");
  const std::string ply_b = read_bytes(bounded.dir + "/scans/paging.ply");
  EXPECT_GT(ply_a.size(), 1000u);
  EXPECT_TRUE(ply_a == ply_b) << "the exported PLYs differ (" << ply_a.size() << " vs " << ply_b.size()
                              << " bytes)";
}

}  // namespace
}  // namespace depthfuse::testing
