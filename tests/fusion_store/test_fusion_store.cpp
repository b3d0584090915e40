// depthfuse-capture (synthetic corner) -> depthfuse-fusion --scan-db FILE, real processes on real
// LCM. (a) a recorded scan passes `depthfuse inspect` and `depthfuse export` writes its cloud;
// (b) the fusion daemon killed with SIGKILL at random moments, 20+ times, resumes each time from
// the file's last checkpoint (the next frame id follows it), the file passes its integrity check
// after every kill, and the final file holds every frame id exactly once; (c) with the frame redo
// log's defaults, a kill at any moment loses at most 30 frames of a 30 Hz capture, also with both
// cores busy; (d)
// checkpoint commands every 0.15 s and then a stop, round after round: every command is answered
// and every stop saves its scan.
#include <cstdlib>
#include <random>

#include "depthfuse/command_t.hpp"
#include "depthfuse/daemon/heartbeat.hpp"
#include "depthfuse/heartbeat_t.hpp"
#include "depthfuse/lcm/channels.hpp"
#include "depthfuse/lcm/codec.hpp"
#include "depthfuse/pose_t.hpp"
#include "depthfuse/store/scan_recorder.hpp"
#include "depthfuse/store/scan_store.hpp"
#include "store_test_util.hpp"
#include "lcm_test_util.hpp"

namespace depthfuse::testing {
namespace {

using std::chrono::milliseconds;
using std::chrono::seconds;

class FusionStore : public ::testing::Test {
 protected:
  void SetUp() override {
    url_ = test_url();
    require_multicast_route(url_);
    config_ = dir_.file("depthfuse.toml");
    std::ofstream(config_) << "[fusion_daemon]\ncheckpoint_interval_s = 0.5\n"
                              "keyframe_every_n_frames = 5\nscan_dir = \"" << dir_.file("scans") << "\"\n";
    db_ = dir_.file("scan.db");
  }
  std::unique_ptr<Process> start_fusion(const std::string& log, std::vector<std::string> prefix = {}) {
    std::vector<std::string> argv = {bin("depthfuse-fusion"), "--key-file", "", "--config", config_, "--lcm", url_,
                                     "--scan-db", db_, "--autostart", "kill-test"};
    argv.insert(argv.begin(), prefix.begin(), prefix.end());
    return std::make_unique<Process>(argv, dir_.file(log));
  }
  std::unique_ptr<Process> start_capture(const std::string& spec, std::vector<std::string> extra) {
    std::vector<std::string> argv = {bin("depthfuse-capture"), "--key-file", "", "--source", "synthetic:" + spec,
                                     "--lcm", url_, "--color", "none"};
    argv.insert(argv.end(), extra.begin(), extra.end());
    return std::make_unique<Process>(argv, dir_.file("capture.log"));
  }
  int cli(std::vector<std::string> args, std::string* out) {
    args.insert(args.begin(), bin("depthfuse"));
    return run_command(args, dir_.file("cli-" + std::to_string(cli_calls_++) + ".log"), out);
  }
  // The last checkpoint's frame id (0 before the first), after an integrity check of the file.
  uint32_t checked_last_frame(const std::string& when) {
    auto store = store::ScanStore::open(db_, store::OpenMode::kReadOnly);
    if (!store) {
      ADD_FAILURE() << when << ": " << store.status().to_string();
      return 0;
    }
    auto integrity = (*store)->integrity_check();
    EXPECT_TRUE(integrity.is_ok()) << when << ": " << integrity.status().to_string();
    if (integrity.is_ok()) {
      std::string problems;
      for (const auto& p : integrity->problems) problems += p + "\n";
      EXPECT_TRUE(integrity->ok()) << when << ":\n" << problems;
    }
    auto last = (*store)->last_checkpoint();
    EXPECT_TRUE(last.is_ok()) << when << ": " << last.status().to_string();
    const uint32_t checkpointed = last.is_ok() && *last ? (*last)->last_frame_id : 0;
    // The frame redo log holds the frames after it that a resume replays.
    auto log = (*store)->frame_log_summary();
    EXPECT_TRUE(log.is_ok()) << when << ": " << log.status().to_string();
    if (log.is_ok() && log->count > 0) {
      EXPECT_EQ(log->first_frame_id, checkpointed + 1) << when;
      return log->last_frame_id;
    }
    return checkpointed;
  }
  void kill_at_random_moments(int kills, const std::string& tag);
  // Frames of the file's redo log after its last checkpoint.
  size_t logged_frames() {
    auto store = store::ScanStore::open(db_, store::OpenMode::kReadOnly);
    if (!store) return 0;
    auto log = (*store)->frame_log_summary();
    return log.is_ok() ? log->count : 0;
  }

  std::string url_;
  store::test::TempDir dir_{"fusion-store"};
  std::string config_, db_;
  int cli_calls_ = 0;
};

// "element vertex N" of a PLY header, -1 when there is none.
int64_t ply_vertex_count(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  std::string line;
  while (std::getline(in, line) && line != "end_header") {
    if (line.rfind("element vertex ", 0) == 0) return std::stoll(line.substr(15));
  }
  return -1;
}

TEST_F(FusionStore, RecordedScanInspectsAndExports) {
  auto fusion = start_fusion("fusion.log");
  std::this_thread::sleep_for(milliseconds(500));
  auto capture = start_capture("corner?frames=12&seed=3", {"--rate", "4"});
  ASSERT_TRUE(capture->wait(seconds(60))) << capture->log();
  ASSERT_EQ(capture->exit_code(), 0) << capture->log();
  std::this_thread::sleep_for(seconds(2));  // the last frames are fused
  fusion->signal(SIGTERM);
  ASSERT_TRUE(fusion->wait(seconds(60))) << fusion->log();
  EXPECT_EQ(fusion->exit_code(), 0) << fusion->log();

  std::string out;
  ASSERT_EQ(cli({"inspect", db_}, &out), 0) << out;
  EXPECT_NE(out.find("integrity      ok"), std::string::npos) << out;
  EXPECT_NE(out.find("(sigterm, frame "), std::string::npos) << out;

  auto store = store::ScanStore::open(db_, store::OpenMode::kReadOnly);
  ASSERT_TRUE(store.is_ok()) << store.status().to_string();
  auto summary = (*store)->summary();
  ASSERT_TRUE(summary.is_ok()) << summary.status().to_string();
  EXPECT_GE(summary->pose_count, 3u) << fusion->log();
  EXPECT_GT(summary->point_count, 10000u);

  const std::string ply = dir_.file("x.ply");
  ASSERT_EQ(cli({"export", db_, "-o", ply}, &out), 0) << out;
  EXPECT_EQ(ply_vertex_count(ply), static_cast<int64_t>(summary->point_count));
  // The daemon's own PLY on stop is the same cloud, streamed from the file.
  EXPECT_EQ(ply_vertex_count(dir_.file("scans/kill-test.ply")), static_cast<int64_t>(summary->point_count))
      << fusion->log();
}

// A scan file's stored id names the files written at the scan's end: one that is not a scan name
// is not resumed, and nothing is written outside scan_dir.
TEST_F(FusionStore, StoredScanIdThatIsNotANameIsNotResumed) {
  const std::string scan_dir = dir_.file("scans");
  for (const std::string id : {"../../escaped", "/tmp/depthfuse-escaped"}) {
    SCOPED_TRACE(id);
    std::filesystem::remove(db_);
    for (const char* ext : {".ply", "-trajectory.txt", ".dfscan"})  // a failed run's leftovers
      std::filesystem::remove(std::filesystem::path(scan_dir) / (id + ext));
    store::ScanMetadata meta;
    meta.scan_id = id;
    ASSERT_TRUE(store::ScanRecorder::create(db_, meta, "", "", store::RecorderConfig{}).is_ok());
    auto fusion = start_fusion("fusion-id.log");
    ASSERT_TRUE(eventually([&] { return fusion->log().find("is not a scan name") != std::string::npos; },
                           seconds(20)))
        << fusion->log();
    fusion->signal(SIGTERM);
    ASSERT_TRUE(fusion->wait(seconds(30))) << fusion->log();
    for (const char* ext : {".ply", "-trajectory.txt", ".dfscan"})
      EXPECT_FALSE(std::filesystem::exists(std::filesystem::path(scan_dir) / (id + ext))) << ext;
  }
}

TEST_F(FusionStore, KilledTwentyTimesResumesFromTheLastCheckpoint) {
  constexpr int kKills = 20;
  // The first pose each round's daemon publishes: registered means ICP found the restored map
  // where the restored pose expects it (a resume without map or pose cannot register its first
  // frame: an empty map has nothing to register against).
  std::mutex mutex;
  std::map<int, bool> first_pose_registered;  // by round
  std::atomic<int> current_round{-1};
  Listener listener(url_);
  ASSERT_TRUE(listener.error().empty()) << listener.error();
  listener.subscribe(lcm::kPoseChannel, [&](const std::string&, const uint8_t* d, size_t n, int64_t) {
    depthfuse::pose_t pose;
    if (lcm::decode_message(d, n, &pose) != lcm::DecodeResult::kOk) return;
    std::lock_guard<std::mutex> lock(mutex);
    first_pose_registered.emplace(current_round.load(), pose.registered != 0);
  });
  listener.start();
  auto capture = start_capture("corner?frames=60&seed=11", {"--rate", "6", "--loop"});
  std::mt19937 rng(std::random_device{}());
  std::uniform_int_distribution<int> kill_after_ms(300, 2500);

  uint32_t checkpoint_frame = 0;  // of the file, as the last kill left it
  int resumes_with_frames = 0;
  for (int round = 0; round <= kKills; ++round) {
    const std::string log = "fusion-" + std::to_string(round) + ".log";
    current_round = round;
    auto fusion = start_fusion(log);
    // The daemon states where it continues: right after the file's last checkpoint.
    const std::string expected = checkpoint_frame == 0
        ? "scan kill-test started"
        : "scan kill-test resumed at frame " + std::to_string(checkpoint_frame + 1);
    EXPECT_TRUE(eventually([&] { return fusion->log().find(expected) != std::string::npos; },
                           seconds(20)))
        << "round " << round << ": expected '" << expected << "':\n" << fusion->log();
    if (checkpoint_frame > 0) ++resumes_with_frames;
    // A resume refills the relocaliser from the file's keyframes before its first frame, and says so.
    if (checkpoint_frame > 0) {
      EXPECT_NE(fusion->log().find("relocalisation keyframes from"), std::string::npos)
          << "round " << round << ":\n" << fusion->log();
    }
    if (round == kKills) {
      // The last round ends cleanly: a final checkpoint.
      std::this_thread::sleep_for(seconds(2));
      fusion->signal(SIGTERM);
      ASSERT_TRUE(fusion->wait(seconds(60))) << fusion->log();
      EXPECT_EQ(fusion->exit_code(), 0) << fusion->log();
    } else {
      std::this_thread::sleep_for(milliseconds(kill_after_ms(rng)));
      fusion->signal(SIGKILL);
      ASSERT_TRUE(fusion->wait(seconds(10)));
      EXPECT_EQ(fusion->exit_code(), 128 + SIGKILL);
    }
    const uint32_t now = checked_last_frame("after round " + std::to_string(round));
    EXPECT_GE(now, checkpoint_frame) << "a checkpoint went missing in round " << round;
    checkpoint_frame = now;
    if (HasFatalFailure()) return;
  }
  capture->signal(SIGTERM);
  listener.stop();
  EXPECT_GT(resumes_with_frames, kKills / 2) << "too few rounds reached a checkpoint";
  int registered_first = 0;
  for (const auto& [round, registered] : first_pose_registered) registered_first += round > 0 && registered;
  // Frames arrive where ICP may legitimately fail (the looping capture jumps back to its start),
  // so most rounds, not all.
  EXPECT_GE(registered_first, resumes_with_frames / 2)
      << "resumed daemons did not track against the restored map and pose";
  std::printf("%d kills, %d resumes from a checkpoint, %d of them registered their first frame, "
              "%u frames in the final file\n",
              kKills, resumes_with_frames, registered_first, checkpoint_frame);

  // Every frame id from 1 to the last checkpoint's exactly once: ids continued across resumes.
  auto store = store::ScanStore::open(db_, store::OpenMode::kReadOnly);
  ASSERT_TRUE(store.is_ok()) << store.status().to_string();
  auto poses = (*store)->read_poses();
  ASSERT_TRUE(poses.is_ok()) << poses.status().to_string();
  ASSERT_EQ(poses->size(), checkpoint_frame);
  for (size_t i = 0; i < poses->size(); ++i) ASSERT_EQ((*poses)[i].frame_id, i + 1);
  EXPECT_GT(checkpoint_frame, static_cast<uint32_t>(kKills)) << "the scan hardly advanced";

  std::string out;
  ASSERT_EQ(cli({"inspect", db_}, &out), 0) << out;
  EXPECT_NE(out.find("integrity      ok"), std::string::npos) << out;
  const std::string ply = dir_.file("after-kills.ply");
  ASSERT_EQ(cli({"export", db_, "-o", ply}, &out), 0) << out;
  EXPECT_GT(ply_vertex_count(ply), 10000);
}

// The frame redo log with the defaults (committed at least every second, full checkpoints every 30
// s): `kills` kill -9s at random moments of a 30 Hz capture, a third within the first second of the
// scan or its resume, each losing at most 30 fused frames (frames lost: fused, their pose
// published, but neither in the file's last checkpoint nor in its log), with nothing fused more
// than 2 s before the kill missing, `depthfuse inspect` passing after each, each resume continuing
// after the last frame the file holds, and `export` of a killed file folding the logged frames in.
void FusionStore::kill_at_random_moments(int kills, const std::string& tag) {
  constexpr int64_t kMaxLost = 30;
  // A frame log commit every second, plus the time it takes to write on a loaded machine.
  constexpr milliseconds kOld(2000);
  std::ofstream(config_) << "[fusion_daemon]\nscan_dir = \"" << dir_.file("scans") << "\"\n";
  // Arrival times of the current round's poses.
  std::mutex mutex;
  std::vector<std::chrono::steady_clock::time_point> poses;
  Listener listener(url_);
  ASSERT_TRUE(listener.error().empty()) << listener.error();
  listener.subscribe(lcm::kPoseChannel, [&](const std::string&, const uint8_t*, size_t, int64_t) {
    std::lock_guard<std::mutex> lock(mutex);
    poses.push_back(std::chrono::steady_clock::now());
  });
  listener.start();
  auto capture = start_capture("corner?frames=60&seed=7", {"--rate", "30", "--loop"});
  std::mt19937 rng(std::random_device{}());
  std::uniform_int_distribution<int> early_ms(50, 1000), any_ms(50, 4000);

  uint32_t checkpoint_frame = 0;
  int64_t most_lost = 0, total_fused = 0;
  int exports_folded = 0;
  for (int round = 0; round < kills; ++round) {
    SCOPED_TRACE(tag + " round " + std::to_string(round));
    const std::string log = "fusion-" + tag + std::to_string(round) + ".log";
    {
      std::lock_guard<std::mutex> lock(mutex);
      poses.clear();
    }
    auto fusion = start_fusion(log);
    const std::string started = checkpoint_frame == 0
        ? "scan kill-test started"
        : "scan kill-test resumed at frame " + std::to_string(checkpoint_frame + 1);
    ASSERT_TRUE(eventually([&] { return fusion->log().find(started) != std::string::npos; }, seconds(60)))
        << "expected '" << started << "':\n" << fusion->log();
    // A third of the kills within the first second of the scan.
    std::this_thread::sleep_for(milliseconds(round % 3 == 0 ? early_ms(rng) : any_ms(rng)));
    const auto killed_at = std::chrono::steady_clock::now();
    fusion->signal(SIGKILL);
    ASSERT_TRUE(fusion->wait(seconds(10)));
    std::this_thread::sleep_for(milliseconds(300));  // poses already on the wire
    int64_t fused = 0, older = 0;
    {
      std::lock_guard<std::mutex> lock(mutex);
      fused = static_cast<int64_t>(poses.size());
      for (const auto& t : poses) older += t < killed_at - kOld;
    }
    const uint32_t now = checked_last_frame("after kill " + std::to_string(round));
    const int64_t lost = static_cast<int64_t>(checkpoint_frame) + fused - now;
    EXPECT_LE(lost, kMaxLost) << fused << " frames fused from frame " << checkpoint_frame + 1
                              << ", the file holds frames up to " << now << ":\n" << fusion->log();
    // However fast this machine fuses: what was fused well before the kill is in the file.
    EXPECT_GE(static_cast<int64_t>(now), static_cast<int64_t>(checkpoint_frame) + older)
        << older << " frames were fused more than " << kOld.count() << " ms before the kill";
    EXPECT_GE(now, checkpoint_frame);
    most_lost = std::max(most_lost, lost);
    total_fused += fused;
    std::string out;
    EXPECT_EQ(cli({"inspect", db_}, &out), 0) << out;
    EXPECT_NE(out.find("integrity      ok"), std::string::npos) << out;
    // Export of the killed file, not resumed: the logged frames are folded in.
    if (const size_t logged = logged_frames(); logged > 0 && round % 4 == 1) {
      EXPECT_EQ(cli({"export", db_, "-o", dir_.file("killed.ply")}, &out), 0) << out;
      EXPECT_NE(out.find(std::to_string(logged) + " logged frames folded in"), std::string::npos) << out;
      ++exports_folded;
    }
    checkpoint_frame = now;
    if (HasFatalFailure()) return;
  }
  capture->signal(SIGTERM);
  listener.stop();
  if (kills >= 8) {  // exports every 4th round, of a file with a log
    EXPECT_GT(exports_folded, 0) << "no export of a killed file had logged frames to fold in";
  }
  std::printf("%s: %d kills: at most %lld frames lost of %lld fused, %u frames in the file\n", tag.c_str(),
              kills, static_cast<long long>(most_lost), static_cast<long long>(total_fused), checkpoint_frame);
  EXPECT_GT(checkpoint_frame, static_cast<uint32_t>(kills)) << "the scan hardly advanced";
}

TEST_F(FusionStore, KilledAtRandomMomentsLosesAtMostOneSecondOfFrames) {
  kill_at_random_moments(12, "k");
}

// The same with both cores taken by busy loops beside the daemons (issue 36: the frame log's
// thread, niced, waited for a core most of the time, and 8 of 20 kills lost more than 30 frames).
// The daemon now waits for the log rather than let it fall a second behind.
TEST_F(FusionStore, KilledUnderLoadLosesAtMostOneSecondOfFrames) {
  std::atomic<bool> busy{true};
  std::vector<std::thread> loops;
  for (int i = 0; i < 2; ++i)
    loops.emplace_back([&] {
      volatile uint64_t spin = 0;
      while (busy.load(std::memory_order_relaxed)) ++spin;
    });
  kill_at_random_moments(5, "load");
  busy = false;
  for (std::thread& t : loops) t.join();
}

// Checkpoint commands every 0.15 s while frames are fused, then a stop, round after round: every
// command is answered (accepted), and every stop saves its scan. The daemon's threads once shared
// one SQLite connection, and the export at a stop read it while the frame log's thread committed a
// record on it: stops failed with "cannot start a transaction within a transaction", and once the
// daemon answered nothing for 90 s (issue 36). DEPTHFUSE_RACE_ROUNDS sets the rounds
// (tools/bench/checkpoint_race.py runs 100 with the command-line client).
TEST_F(FusionStore, CheckpointCommandsThenStopEveryRound) {
  const char* env = std::getenv("DEPTHFUSE_RACE_ROUNDS");
  const int rounds = env ? std::atoi(env) : 6;
  constexpr int kCommands = 8;
  // Heartbeats at 20 Hz repeat each acknowledgement until the next command, should one be missed.
  std::ofstream(config_) << "[lcm]\nkey_file = \"\"\n[fusion_daemon]\nscan_dir = \""
                         << dir_.file("scans") << "\"\nmin_scan_interval_s = 0\nheartbeat_rate_hz = 20\n";
  struct Ack {
    int8_t result;
    std::string message;
  };
  std::mutex mutex;
  std::map<int64_t, Ack> acks;
  int64_t frames_out = -1;  // no heartbeat yet
  Listener listener(url_);
  ASSERT_TRUE(listener.error().empty()) << listener.error();
  listener.subscribe(lcm::kHeartbeatChannel, [&](const std::string&, const uint8_t* d, size_t n, int64_t) {
    depthfuse::heartbeat_t hb;
    if (lcm::decode_message(d, n, &hb) != lcm::DecodeResult::kOk || hb.name != "fusion") return;
    std::lock_guard<std::mutex> lock(mutex);
    frames_out = hb.frames_out;
    if (hb.last_command_id > 0) acks.emplace(hb.last_command_id, Ack{hb.last_command_result, hb.last_command_message});
  });
  listener.start();
  auto fusion = std::make_unique<Process>(
      std::vector<std::string>{bin("depthfuse-fusion"), "--config", config_, "--lcm", url_},
      dir_.file("fusion-race.log"));
  auto capture = start_capture("corner?frames=60&seed=9", {"--rate", "30", "--loop"});
  int64_t next_id = 1000;
  auto send = [&](int8_t action, const std::string& argument = "") {
    depthfuse::command_t cmd{};
    cmd.protocol_version = depthfuse::command_t::PROTOCOL_VERSION;
    cmd.command_id = next_id++;
    cmd.target = "fusion";
    cmd.action = action;
    cmd.argument = argument;
    cmd.sender = "race-test";
    EXPECT_TRUE(listener.lcm()->publish_message(lcm::kCommandChannel, cmd).is_ok());
    return cmd.command_id;
  };
  // The command's acknowledgement, or nothing after `timeout`.
  auto answer = [&](int64_t id, seconds timeout) -> std::optional<Ack> {
    const bool answered = eventually([&] {
      std::lock_guard<std::mutex> lock(mutex);
      return acks.count(id) > 0;
    }, timeout, milliseconds(10));
    if (!answered) return std::nullopt;
    std::lock_guard<std::mutex> lock(mutex);
    return acks.at(id);
  };
  auto fused = [&] {
    std::lock_guard<std::mutex> lock(mutex);
    return frames_out;
  };
  ASSERT_TRUE(eventually([&] { return fused() >= 0; }, seconds(20))) << "no heartbeat:\n" << fusion->log();
  for (int round = 0; round < rounds; ++round) {
    SCOPED_TRACE("round " + std::to_string(round));
    const auto started = answer(send(depthfuse::command_t::ACTION_START, "race" + std::to_string(round)),
                                seconds(20));
    ASSERT_TRUE(started) << "start not answered:\n" << fusion->log();
    ASSERT_EQ(started->result, depthfuse::heartbeat_t::COMMAND_RESULT_OK) << started->message;
    const int64_t before = fused();
    ASSERT_TRUE(eventually([&] { return fused() > before + 2; }, seconds(20))) << fusion->log();
    std::vector<int64_t> ids;
    for (int k = 0; k < kCommands; ++k) {
      ids.push_back(send(depthfuse::command_t::ACTION_CHECKPOINT_NOW));
      std::this_thread::sleep_for(milliseconds(150));
    }
    const int64_t stop_id = send(depthfuse::command_t::ACTION_STOP);
    for (const int64_t id : ids) {
      const auto a = answer(id, seconds(30));
      ASSERT_TRUE(a) << "checkpoint command " << id << " not answered:\n" << fusion->log();
      EXPECT_EQ(a->result, depthfuse::heartbeat_t::COMMAND_RESULT_OK) << a->message;
    }
    const auto stopped = answer(stop_id, seconds(60));
    ASSERT_TRUE(stopped) << "stop not answered:\n" << fusion->log();
    EXPECT_EQ(stopped->result, depthfuse::heartbeat_t::COMMAND_RESULT_OK) << stopped->message;
    EXPECT_NE(stopped->message.find(" saved: "), std::string::npos) << stopped->message;
    if (HasFatalFailure()) return;
  }
  capture->signal(SIGTERM);
  fusion->signal(SIGTERM);
  ASSERT_TRUE(fusion->wait(seconds(60)));
  EXPECT_EQ(fusion->exit_code(), 0) << fusion->log();
  listener.stop();
  std::string out;
  EXPECT_EQ(cli({"inspect", dir_.file("scans/race0.dfscan")}, &out), 0) << out;
}

TEST_F(FusionStore, FullDiskIsReportedAndTheLastGoodCheckpointKept) {
  // Heartbeats every 50 ms: the first that counts a failed checkpoint must say why, however soon
  // after the failure it comes (a frame collects a background checkpoint's outcome, and the
  // periodic checkpoint call that once reported it came up to checkpoint_interval_s later).
  std::ofstream(config_, std::ios::app) << "heartbeat_rate_hz = 20\n";
  std::mutex mutex;
  std::optional<depthfuse::heartbeat_t> last_hb, first_failed, first_log_failed;
  Listener listener(url_);
  ASSERT_TRUE(listener.error().empty()) << listener.error();
  listener.subscribe(lcm::kHeartbeatChannel, [&](const std::string&, const uint8_t* d, size_t n,
                                                   int64_t) {
    depthfuse::heartbeat_t hb;
    if (lcm::decode_message(d, n, &hb) != lcm::DecodeResult::kOk || hb.name != "fusion") return;
    std::lock_guard<std::mutex> lock(mutex);
    last_hb = hb;
    if (!first_failed && daemon::counter_value(hb, "checkpoint_failures") > 0) first_failed = hb;
    if (!first_log_failed && daemon::counter_value(hb, "frame_log_failures") > 0) first_log_failed = hb;
  });
  listener.start();
  auto hb = [&] {
    std::lock_guard<std::mutex> lock(mutex);
    return last_hb;
  };

  // A 12 MB file size limit: the first checkpoints fit, the growing scan soon does not. SIGXFSZ
  // is ignored (inherited through exec), so writes fail with EFBIG instead of killing the daemon.
  auto old_handler = ::signal(SIGXFSZ, SIG_IGN);
  auto fusion = start_fusion("fusion-full.log", {"/usr/bin/prlimit", "--fsize=12000000", "--"});
  ::signal(SIGXFSZ, old_handler);
  std::this_thread::sleep_for(milliseconds(500));
  auto capture = start_capture("corner?frames=60&seed=5", {"--rate", "5", "--loop"});

  ASSERT_TRUE(eventually([&] {
    std::lock_guard<std::mutex> lock(mutex);
    return first_failed.has_value();
  }, seconds(90))) << fusion->log();
  const auto failed = [&] {
    std::lock_guard<std::mutex> lock(mutex);
    return *first_failed;
  }();
  EXPECT_NE(failed.last_error.find("checkpoint to frame"), std::string::npos) << failed.last_error;
  EXPECT_GT(daemon::counter_value(failed, "checkpoints_written"), 0) << fusion->log();
  // Fusion goes on.
  EXPECT_TRUE(eventually([&] { return hb()->frames_out > failed.frames_out + 2; }, seconds(30)))
      << fusion->log();
  // The frame log's appends fail too once its file cannot grow: counted, and the heartbeat that
  // first counts one says why (issue 36: the log stopped with frame_log_failures still 0). Its
  // failures hold nothing up: fusion goes on.
  ASSERT_TRUE(eventually([&] {
    std::lock_guard<std::mutex> lock(mutex);
    return first_log_failed.has_value();
  }, seconds(90))) << fusion->log();
  const auto log_failed = [&] {
    std::lock_guard<std::mutex> lock(mutex);
    return *first_log_failed;
  }();
  EXPECT_NE(log_failed.last_error.find("frame log"), std::string::npos) << log_failed.last_error;
  EXPECT_TRUE(eventually([&] { return hb()->frames_out > log_failed.frames_out + 5; }, seconds(30)))
      << fusion->log();
  EXPECT_TRUE(fusion->running()) << fusion->log();
  fusion->signal(SIGKILL);
  ASSERT_TRUE(fusion->wait(seconds(10)));
  capture->signal(SIGTERM);

  // The last good checkpoint is there and the file is sound.
  EXPECT_GT(checked_last_frame("after the full disk"), 0u);
}

}  // namespace
}  // namespace depthfuse::testing
