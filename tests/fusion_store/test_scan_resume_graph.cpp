// Kill -9 after a loop closure, resume: the pose graph and the corrected map come back. A scan of
// the analytic corner through ScanSession (the fusion daemon's path over the SQLite sink) goes out
// along an arc and back, so that the way back closes a loop; it is checkpointed after the closure
// (a periodic checkpoint, written in the background) and its process is killed with SIGKILL a few
// frames later. A new session resumes the file: the graph (keyframes, edges, version), the map's
// deformation version, the chunks (versions, points), the points waiting for chunks that had not
// followed the correction and the merge passes left for the sweep are what the checkpoint held, and a further closure after the resume
// moves the poses and points fused before the crash. The same walk over a budget that evicts what
// the camera left behind, ended after its closure, leaves a file whose chunks all follow it.
#include <gtest/gtest.h>
#include <signal.h>
#include <sys/wait.h>
#include <unistd.h>

#include <algorithm>
#include <chrono>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <map>
#include <sstream>
#include <thread>

#include "core_test_util.hpp"
#include "depthfuse/store/frame_log_replay.hpp"
#include "depthfuse/store/scan_store.hpp"
#include "lcm_test_util.hpp"
#include "memory_budget.hpp"
#include "scan_session.hpp"
#include "sqlite_checkpoint_sink.hpp"
#include "store_test_util.hpp"

namespace depthfuse::testing {
namespace {

// A camera on a circle of radius 2.4 m round the corner's vertical axis, looking into it.
Pose on_arc(double azimuth_deg) {
  const double a = azimuth_deg * M_PI / 180.0;
  return test::look_at({2.4 * std::cos(a), 2.4 * std::sin(a), 1.4}, {0.3, 0.3, 0.4});
}

// `frame_log`: the daemon's redo log (its default interval). Without it a resume starts from the
// checkpoint exactly (the log replays the frames fused after it): what is compared is what the
// checkpoint holds.
AppConfig scan_config(const std::string& dir, bool frame_log) {
  AppConfig config;
  config.fusion.scan_dir = dir + "/scans";
  if (!frame_log) config.fusion.frame_log_interval_s = 0;
  // A short loop: the way back may close on keyframes a few keyframes and half a metre behind.
  config.reconstruction.loop_closure.min_keyframes_back = 3;
  config.reconstruction.loop_closure.min_path_m = 0.5;
  // The correction these tests wait for comes from the drift of a track standing at azimuth 2
  // degrees, where the wall y = 0 is seen edge on and nothing in the view fixes the position along
  // the arc: the track runs on under the motion prior, swings out and back, and the closer's
  // answer must come during the swing. Which frame it comes at depends on every earlier pose, so
  // the walk's first step (the one frame tracked without a prediction) is tracked as these tests
  // were written for. Without a drift of its own the corner walk tracks to within the 2 mm a
  // correction must move, and no correction comes at all.
  config.reconstruction.registration.tracking_levels_without_motion = 3;
  return config;
}

class Walk {
 public:
  explicit Walk(fusiond::ScanSession* session) : session_(session) {}
  // Frames from azimuth a to b in steps of step_deg.
  bool go(double from_deg, double to_deg, double step_deg) {
    const int n = static_cast<int>(std::lround(std::abs(to_deg - from_deg) / step_deg));
    for (int i = 1; i <= n; ++i)
      if (!frame(from_deg + (to_deg - from_deg) * i / n)) return false;
    return true;
  }
  // Frames standing at azimuth a until the loop closer's correction is applied (graph version
  // above `version`), at most a few seconds of them.
  bool until_version_above(uint32_t version, double at_deg) {
    for (int i = 0; i < 300; ++i) {
      if (session_->path()->graph().version() > version) return true;
      if (!frame(at_deg)) return false;
      std::this_thread::sleep_for(std::chrono::milliseconds(20));
    }
    return session_->path()->graph().version() > version;
  }
  bool frame(double azimuth_deg) {
    Frame f = test::render_corner(on_arc(azimuth_deg));
    f.sequence = sequence_;
    f.utime = 1700000000000000LL + static_cast<int64_t>(sequence_) * 1000000 / 30;
    ++sequence_;
    auto out = session_->process(f);
    if (!out.is_ok()) {
      last_problem = out.status().to_string();
      return false;
    }
    // A frame the tracking refuses is not fused; the scan goes on (as the daemon's does).
    if (out->report.fused())
      ++fused;
    else
      last_problem = "frame " + std::to_string(out->report.frame_id) +
                     " not fused (graph version " +
                     std::to_string(session_->path()->graph().version()) + ")";
    ++processed;
    return true;
  }
  uint32_t sequence_ = 1;
  std::string last_problem;
  size_t fused = 0, processed = 0;

 private:
  fusiond::ScanSession* session_;
};

// What the loop closer did, for a test that waited for a correction in vain.
std::string closure_stats(fusiond::ScanSession& session) {
  const LoopClosureStats st = session.path()->loop_closure_stats();
  return std::to_string(session.path()->graph().keyframes().size()) + " keyframes, " +
         std::to_string(st.keyframes_searched) + " searched, " + std::to_string(st.candidates) +
         " candidates, " + std::to_string(st.aligned) + " aligned, " + std::to_string(st.gated) +
         " gated, " + std::to_string(st.rejected) + " rejected, " +
         std::to_string(st.optimisations) + " optimisations";
}

// Points waiting for their chunk to follow a correction: key and version -> points, coordinate sum.
using PendingByKey = std::map<std::tuple<int, int, int, uint32_t>, std::pair<size_t, double>>;

// What a checkpoint held, as text: the graph, the deformation's version, every chunk.
struct Held {
  std::vector<uint32_t> keyframe_frames;
  std::vector<Pose> keyframe_poses;
  size_t odometry = 0, loops = 0;
  uint32_t graph_version = 0, deformation_version = 0;
  uint32_t next_sequence = 0;
  std::vector<Eigen::Vector3d> trajectory;  // the camera's positions, corrected, frame by frame
  // key -> version, points, sum of the points' coordinates
  std::map<std::tuple<int, int, int>, std::tuple<uint32_t, size_t, double>> chunks;
  PendingByKey pending;
  // The merge passes queued for the sweep, in order: key, first point, from version.
  std::vector<std::tuple<int, int, int, uint32_t, uint32_t>> merges;
};

std::vector<std::tuple<int, int, int, uint32_t, uint32_t>> merges_of(const DeformationHistory& h) {
  std::vector<std::tuple<int, int, int, uint32_t, uint32_t>> out;
  for (const DeformationHistory::QueuedMerge& m : h.merges)
    out.emplace_back(m.key.x, m.key.y, m.key.z, m.first_point, m.from_version);
  return out;
}

// The same chunk versions with the same points (count, coordinate sum).
void expect_same_pending(const PendingByKey& actual, const PendingByKey& expected,
                         const std::string& what) {
  ASSERT_EQ(actual.size(), expected.size()) << what;
  for (const auto& [key, v] : expected) {
    const auto it = actual.find(key);
    ASSERT_NE(it, actual.end()) << what;
    EXPECT_EQ(it->second.first, v.first) << what;
    EXPECT_NEAR(it->second.second, v.second, 1e-6) << what;
  }
}

double coordinate_sum(const PointArrays& a) {
  double sum = 0;
  for (size_t i = 0; i < a.size(); ++i) sum += a.position_m[i].cast<double>().sum();
  return sum;
}

PendingByKey pending_of(const std::vector<PendingPoints>& pending) {
  PendingByKey out;
  for (const PendingPoints& p : pending)
    out[{p.key.x, p.key.y, p.key.z, p.version}] = {p.points.size(), coordinate_sum(p.points)};
  return out;
}

void write_held(const std::string& path, const Held& h) {
  std::ofstream out(path);
  out.precision(17);
  out << h.keyframe_frames.size() << " " << h.odometry << " " << h.loops << " " << h.graph_version
      << " " << h.deformation_version << " " << h.next_sequence << "\n";
  for (size_t k = 0; k < h.keyframe_frames.size(); ++k) {
    out << h.keyframe_frames[k];
    for (int i = 0; i < 3; ++i) out << " " << h.keyframe_poses[k].translation()[i];
    out << "\n";
  }
  out << h.trajectory.size() << "\n";
  for (const Eigen::Vector3d& p : h.trajectory)
    out << p.x() << " " << p.y() << " " << p.z() << "\n";
  out << h.chunks.size() << "\n";
  for (const auto& [key, v] : h.chunks)
    out << std::get<0>(key) << " " << std::get<1>(key) << " " << std::get<2>(key) << " "
        << std::get<0>(v) << " " << std::get<1>(v) << " " << std::get<2>(v) << "\n";
  out << h.pending.size() << "\n";
  for (const auto& [key, v] : h.pending)
    out << std::get<0>(key) << " " << std::get<1>(key) << " " << std::get<2>(key) << " "
        << std::get<3>(key) << " " << v.first << " " << v.second << "\n";
  out << h.merges.size() << "\n";
  for (const auto& [x, y, z, first, from] : h.merges)
    out << x << " " << y << " " << z << " " << first << " " << from << "\n";
}

Held read_held(const std::string& path) {
  Held h;
  std::ifstream in(path);
  size_t keyframes = 0;
  in >> keyframes >> h.odometry >> h.loops >> h.graph_version >> h.deformation_version >>
      h.next_sequence;
  for (size_t k = 0; k < keyframes; ++k) {
    uint32_t frame = 0;
    Pose T = Pose::Identity();
    in >> frame >> T.translation().x() >> T.translation().y() >> T.translation().z();
    h.keyframe_frames.push_back(frame);
    h.keyframe_poses.push_back(T);
  }
  size_t poses = 0;
  in >> poses;
  h.trajectory.resize(poses);
  for (Eigen::Vector3d& p : h.trajectory) in >> p.x() >> p.y() >> p.z();
  // Chunks and pending points alike: a count, then "x y z version points sum" each.
  const auto read_rows = [&](const auto& add) {
    size_t rows = 0;
    in >> rows;
    for (size_t r = 0; r < rows; ++r) {
      int x, y, z;
      uint32_t version;
      size_t points;
      double sum;
      in >> x >> y >> z >> version >> points >> sum;
      add(x, y, z, version, points, sum);
    }
  };
  read_rows([&](int x, int y, int z, uint32_t version, size_t points, double sum) {
    h.chunks[{x, y, z}] = {version, points, sum};
  });
  read_rows([&](int x, int y, int z, uint32_t version, size_t points, double sum) {
    h.pending[{x, y, z, version}] = {points, sum};
  });
  size_t merges = 0;
  in >> merges;
  for (size_t m = 0; m < merges; ++m) {
    int x, y, z;
    uint32_t first, from;
    in >> x >> y >> z >> first >> from;
    h.merges.emplace_back(x, y, z, first, from);
  }
  return h;
}

// `depthfuse inspect` on a copy of the scan damaged by `sql`: it fails and names `what`.
void expect_inspect_names(const std::string& dir, const std::string& scan, const std::string& name,
                          const std::string& sql, const std::string& what) {
  const std::string copy = dir + "/" + name + ".dfscan";
  std::filesystem::copy_file(scan, copy);
  // The killed writer's last checkpoint may still be in the write-ahead log only.
  if (std::filesystem::exists(scan + "-wal"))
    std::filesystem::copy_file(scan + "-wal", copy + "-wal");
  store::test::exec_sql(copy, sql);
  std::string out;
  EXPECT_EQ(run_command({bin("depthfuse"), "inspect", copy}, dir + "/" + name + ".log", &out), 1)
      << out;
  EXPECT_NE(out.find(what), std::string::npos) << out;
}

// The child: out along the arc and back until the loop closes, a checkpoint, what it held written
// to `held_path`, a few frames more, then SIGKILL. Exit codes name the step that failed.
[[noreturn]] void scan_and_die(const std::string& dir, const std::string& held_path,
                               bool frame_log) {
  const AppConfig config = scan_config(dir, frame_log);
  fusiond::SqliteCheckpointSink sink(config, fusiond::SqliteSinkOptions{dir + "/loop.dfscan"});
  fusiond::ScanSession session(config, sink);
  if (!session.start("loop").is_ok()) _exit(10);
  Walk walk(&session);
  if (!walk.go(0, 1, 1) || !walk.go(1, 45, 0.75) || !walk.go(45, 2, 0.75)) _exit(11);
  if (!walk.until_version_above(0, 2)) _exit(12);
  if (!walk.frame(2)) _exit(13);  // the map follows the correction around the camera
  // The daemon's periodic checkpoint: written by the recorder's thread from a snapshot taken now.
  if (!session.checkpoint("periodic", fusiond::FusionProgress{}).is_ok()) _exit(14);
  for (int i = 0; sink.checkpoint_in_flight(); ++i) {
    if (i > 1000) _exit(16);
    std::this_thread::sleep_for(std::chrono::milliseconds(10));
  }
  Held h;
  const ScanGraph& g = session.path()->graph();
  for (const GraphKeyframe& k : g.keyframes()) {
    h.keyframe_frames.push_back(k.frame_id);
    h.keyframe_poses.push_back(k.T_world_kf);
  }
  h.odometry = g.odometry().size();
  h.loops = g.loops().size();
  h.graph_version = g.version();
  h.deformation_version = session.reconstructor()->deformation().version();
  h.next_sequence = walk.sequence_;
  for (const StampedPose& p : session.trajectory())
    h.trajectory.push_back(p.T_world_cam.translation());
  session.reconstructor()->map().for_each_chunk([&](const ChunkKey& key, const Chunk& c) {
    if (!c.points().empty())
      h.chunks[{key.x, key.y, key.z}] = {c.version, c.points().size(), coordinate_sum(c.points())};
  });
  h.pending = pending_of(session.reconstructor()->deformation().pending());
  h.merges = merges_of(session.reconstructor()->deformation().history());
  write_held(held_path, h);
  // Fused, not checkpointed: lost with the process, or (with the frame log) logged and replayed.
  walk.go(2, 6, 0.75);
  if (frame_log) std::this_thread::sleep_for(std::chrono::milliseconds(1500));
  ::kill(::getpid(), SIGKILL);
  _exit(15);
}

// Runs scan_and_die in a child process and returns what its checkpoint held.
Held scan_and_kill(const std::string& dir, bool frame_log) {
  const std::string held_path = dir + "/held.txt";
  const pid_t child = ::fork();
  EXPECT_GE(child, 0);
  if (child == 0) scan_and_die(dir, held_path, frame_log);
  int status = 0;
  EXPECT_EQ(::waitpid(child, &status, 0), child);
  EXPECT_TRUE(WIFSIGNALED(status) && WTERMSIG(status) == SIGKILL)
      << "the scan's process ended with " << (WIFEXITED(status) ? WEXITSTATUS(status) : -1)
      << " before it was killed";
  return read_held(held_path);
}

TEST(ScanResume, KillAfterAClosureKeepsTheGraphAndTheCorrectedMap) {
  const std::string dir = temp_dir("scan-resume-graph");
  const Held held = scan_and_kill(dir, /*frame_log=*/false);
  ASSERT_GE(held.loops, 1u);
  ASSERT_GE(held.graph_version, 1u);
  ASSERT_FALSE(held.chunks.empty());
  // The checkpoint came a frame after the correction, with the deformation's sweep far from done:
  // points wait for chunks that have not followed it, and the checkpoint stores them as they are.
  EXPECT_FALSE(held.pending.empty());
  // And the merge passes of the chunks moved before the frame was registered wait for the sweep.
  EXPECT_FALSE(held.merges.empty());

  // The file as a reader sees it: the graph, and every chunk's version and points.
  std::vector<uint32_t> stored_frames;
  {
    auto reader = store::ScanStore::open(dir + "/loop.dfscan", store::OpenMode::kReadOnly);
    ASSERT_TRUE(reader.is_ok()) << reader.status().to_string();
    auto rows = (*reader)->list_chunks();
    ASSERT_TRUE(rows.is_ok());
    size_t compared = 0;
    for (const store::ChunkInfo& c : *rows) {
      const auto it = held.chunks.find({c.key.x, c.key.y, c.key.z});
      ASSERT_NE(it, held.chunks.end()) << store::to_string(c.key);
      EXPECT_EQ(c.version, std::get<0>(it->second)) << store::to_string(c.key);
      EXPECT_EQ(c.point_count, std::get<1>(it->second)) << store::to_string(c.key);
      ++compared;
    }
    EXPECT_EQ(compared, held.chunks.size());
    // The points waiting for chunks that had not followed the correction, as they were.
    auto pending = (*reader)->read_pending();
    ASSERT_TRUE(pending.is_ok()) << pending.status().to_string();
    expect_same_pending(pending_of(*pending), held.pending, "stored");
    // The stored poses are the corrected ones, the session's at the checkpoint.
    auto poses = (*reader)->read_poses();
    ASSERT_TRUE(poses.is_ok());
    ASSERT_EQ(poses->size(), held.trajectory.size());
    for (const store::PoseRecord& p : *poses) stored_frames.push_back(p.frame_id);
    for (size_t i = 0; i < poses->size(); ++i)
      ASSERT_LT(((*poses)[i].T_world_cam.translation() - held.trajectory[i]).norm(), 1e-6)
          << "the stored pose of frame " << (*poses)[i].frame_id << " is not the corrected one";
    auto integrity = (*reader)->integrity_check();
    ASSERT_TRUE(integrity.is_ok());
    EXPECT_TRUE(integrity->ok()) << integrity->problems.front();
    EXPECT_EQ(integrity->graph_keyframes_checked, held.keyframe_frames.size());
  }

  // A damaged row of the graph is named.
  expect_inspect_names(dir, dir + "/loop.dfscan", "damaged-keyframe",
                       "UPDATE graph_keyframes SET utime = utime + 1 WHERE keyframe = 3;",
                       "keyframe 3 of the pose graph: checksum mismatch");
  expect_inspect_names(dir, dir + "/loop.dfscan", "damaged-graph",
                       "UPDATE graph SET version = version + 1;", "pose graph: checksum mismatch");

  const AppConfig config = scan_config(dir, /*frame_log=*/false);
  fusiond::SqliteCheckpointSink sink(config, fusiond::SqliteSinkOptions{dir + "/loop.dfscan"});
  fusiond::ScanSession session(config, sink);
  auto started = session.start("loop");
  ASSERT_TRUE(started.is_ok()) << started.status().to_string();
  const ScanGraph& g = session.path()->graph();
  ASSERT_EQ(g.keyframes().size(), held.keyframe_frames.size());
  for (size_t k = 0; k < held.keyframe_frames.size(); ++k) {
    EXPECT_EQ(g.keyframes()[k].frame_id, held.keyframe_frames[k]);
    EXPECT_LT(
        (g.keyframes()[k].T_world_kf.translation() - held.keyframe_poses[k].translation()).norm(),
        1e-9);
    ASSERT_TRUE(g.keyframes()[k].cloud);
    EXPECT_GT(g.keyframes()[k].cloud->size(), 100u);
  }
  EXPECT_EQ(g.odometry().size(), held.odometry);
  EXPECT_EQ(g.loops().size(), held.loops);
  EXPECT_EQ(g.version(), held.graph_version);
  EXPECT_EQ(session.reconstructor()->deformation().version(), held.deformation_version);
  EXPECT_EQ(session.reconstructor()->deformation().keyframe_count(), held.keyframe_frames.size());
  size_t resident = 0;
  session.reconstructor()->map().for_each_chunk([&](const ChunkKey& key, const Chunk& c) {
    const auto it = held.chunks.find({key.x, key.y, key.z});
    if (it == held.chunks.end()) return;
    ++resident;
    EXPECT_EQ(c.version, std::get<0>(it->second)) << store::to_string(key);
    EXPECT_EQ(c.points().size(), std::get<1>(it->second)) << store::to_string(key);
    EXPECT_NEAR(coordinate_sum(c.points()), std::get<2>(it->second), 1e-6) << store::to_string(key);
  });
  EXPECT_GT(resident, 0u);
  // The merge passes the sweep had not run: queued again, in the same order.
  EXPECT_EQ(merges_of(session.reconstructor()->deformation().history()), held.merges);
  expect_same_pending(pending_of(session.reconstructor()->deformation().pending()), held.pending,
                      "resumed");
  // The trajectory knows its frames: a correction after the resume moves every pose from before
  // the crash with its keyframe (the last keyframe at or before the frame).
  ASSERT_EQ(session.trajectory().size(), stored_frames.size());
  std::vector<Pose> poses_before;
  for (const StampedPose& p : session.trajectory()) poses_before.push_back(p.T_world_cam);
  std::vector<Pose> keyframes_before;
  for (const GraphKeyframe& k : g.keyframes()) keyframes_before.push_back(k.T_world_kf);
  const auto keyframe_of = [&](uint32_t frame_id) {
    size_t k = 0;
    while (k + 1 < keyframes_before.size() && g.keyframes()[k + 1].frame_id <= frame_id) ++k;
    return k;
  };
  const auto motion_of = [&](size_t k) {
    return Pose(g.keyframes()[k].T_world_kf * keyframes_before[k].inverse());
  };
  const auto largest_motion_m = [&] {
    double m = 0;
    for (size_t k = 0; k < keyframes_before.size(); ++k)
      m = std::max(m, motion_of(k).translation().norm());
    return m;
  };

  // On from where the checkpoint left the camera: out along the arc and back again, over the
  // keyframes of before the crash, until a closure on them is applied. A closure whose loops agree
  // with the odometry may move them by microns: the walk stands until one has moved them
  // measurably (a few closures at most).
  Walk walk(&session);
  walk.sequence_ = held.next_sequence;
  ASSERT_TRUE(walk.go(2, 45, 0.75) && walk.go(45, 2, 0.75)) << walk.last_problem;
  EXPECT_GE(walk.fused, walk.processed * 9 / 10) << walk.last_problem;
  ASSERT_TRUE(walk.until_version_above(held.graph_version, 2))
      << "no closure after the resume: " << closure_stats(session);
  ASSERT_TRUE(walk.frame(2));
  for (int closures = 1; closures < 4 && largest_motion_m() <= 1e-4; ++closures) {
    ASSERT_TRUE(walk.until_version_above(g.version(), 2))
        << "no further closure after the resume: " << closure_stats(session);
    ASSERT_TRUE(walk.frame(2));
  }
  EXPECT_GT(session.reconstructor()->deformation().version(), held.deformation_version);
  ASSERT_GT(largest_motion_m(), 1e-4) << "the closures did not move the keyframes of before the crash";
  for (size_t i = 0; i < stored_frames.size(); ++i) {
    const size_t k = keyframe_of(stored_frames[i]);
    const Pose expected = motion_of(k) * poses_before[i];
    EXPECT_LT((session.trajectory()[i].T_world_cam.translation() - expected.translation()).norm(),
              1e-6)
        << "the pose of frame " << stored_frames[i] << " did not move with keyframe " << k;
  }
  // The points fused before the crash followed it: chunks from the file brought up to date.
  EXPECT_GT(session.reconstructor()->deformation().stats().points_updated, 0u);
}

// With the frame redo log, the frames fused after the checkpoint are replayed on the restored
// graph's map: the graph and the deformation are the checkpoint's, the frames after it come back,
// no chunk is in a version the map has not reached, and the scan goes on.
TEST(ScanResume, KillAfterAClosureWithTheFrameLogReplaysOnTheRestoredGraph) {
  const std::string dir = temp_dir("scan-resume-graph-log");
  const Held held = scan_and_kill(dir, /*frame_log=*/true);
  ASSERT_GE(held.graph_version, 1u);

  // `depthfuse export` of the killed file folds the logged frames in memory, in the graph's
  // version: the chunks they fused into followed the correction first (fusion also looks through
  // stale chunks it does not fuse into: those may stay behind), and the points waiting for chunks
  // still in the file come with the fold.
  {
    auto reader = store::ScanStore::open(dir + "/loop.dfscan", store::OpenMode::kReadOnly);
    ASSERT_TRUE(reader.is_ok()) << reader.status().to_string();
    auto last = (*reader)->last_checkpoint();
    ASSERT_TRUE(last.is_ok() && *last);
    auto replay = store::replay_frame_log(**reader, scan_config(dir, true).reconstruction);
    ASSERT_TRUE(replay.is_ok()) << replay.status().to_string();
    ASSERT_FALSE(replay->poses.empty());
    size_t touched = 0, current = 0;
    replay->map->for_each_chunk([&](const ChunkKey&, const Chunk& c) {
      if (c.last_touched_frame <= (*last)->last_frame_id) return;
      ++touched;
      current += c.version == held.deformation_version;
    });
    EXPECT_GT(current, touched / 2) << touched << " chunks touched";
    EXPECT_FALSE(replay->pending.empty());
    std::string out;
    ASSERT_EQ(run_command({bin("depthfuse"), "export", dir + "/loop.dfscan", "-o",
                           dir + "/killed.ply"},
                          dir + "/export.log", &out),
              0)
        << out;
    EXPECT_NE(out.find("logged frames folded in"), std::string::npos) << out;
  }

  // `depthfuse inspect --fold-log` on a copy replays the logged frames as a resume does: in the
  // graph's version, keeping the points waiting for chunks it did not bring up to date.
  {
    const std::string copy = dir + "/folded.dfscan";
    std::filesystem::copy_file(dir + "/loop.dfscan", copy);
    if (std::filesystem::exists(dir + "/loop.dfscan-wal"))
      std::filesystem::copy_file(dir + "/loop.dfscan-wal", copy + "-wal");
    PendingByKey before;
    {
      auto reader = store::ScanStore::open(copy, store::OpenMode::kReadOnly);
      ASSERT_TRUE(reader.is_ok()) << reader.status().to_string();
      auto pending = (*reader)->read_pending();
      ASSERT_TRUE(pending.is_ok()) << pending.status().to_string();
      before = pending_of(*pending);
    }
    ASSERT_FALSE(before.empty());
    std::string out;
    ASSERT_EQ(run_command({bin("depthfuse"), "inspect", "--fold-log", copy}, dir + "/fold.log", &out), 0)
        << out;
    auto reader = store::ScanStore::open(copy, store::OpenMode::kReadOnly);
    ASSERT_TRUE(reader.is_ok()) << reader.status().to_string();
    auto pending = (*reader)->read_pending();
    ASSERT_TRUE(pending.is_ok()) << pending.status().to_string();
    const auto after = pending_of(*pending);
    auto chunks = (*reader)->list_chunks();
    ASSERT_TRUE(chunks.is_ok());
    auto graph = (*reader)->graph_summary();
    ASSERT_TRUE(graph.is_ok() && *graph);
    // Each row is still there, or its chunk was brought up to date (and took its points).
    size_t kept = 0;
    for (const auto& [key, v] : before) {
      if (after.count(key)) {
        ++kept;
        continue;
      }
      bool current = false;
      for (const store::ChunkInfo& c : *chunks)
        if (c.key == ChunkKey{std::get<0>(key), std::get<1>(key), std::get<2>(key)})
          current = c.version == (*graph)->deformation_version;
      EXPECT_TRUE(current) << "the points pending for chunk (" << std::get<0>(key) << ","
                           << std::get<1>(key) << "," << std::get<2>(key)
                           << ") were dropped while it stayed stale";
    }
    EXPECT_GT(kept, 0u);
    auto integrity = (*reader)->integrity_check();
    ASSERT_TRUE(integrity.is_ok());
    EXPECT_TRUE(integrity->ok()) << integrity->problems.front();
  }
  const AppConfig config = scan_config(dir, /*frame_log=*/true);
  fusiond::SqliteCheckpointSink sink(config, fusiond::SqliteSinkOptions{dir + "/loop.dfscan"});
  fusiond::ScanSession session(config, sink);
  auto started = session.start("loop");
  ASSERT_TRUE(started.is_ok()) << started.status().to_string();
  const ScanGraph& g = session.path()->graph();
  ASSERT_EQ(g.keyframes().size(), held.keyframe_frames.size());
  EXPECT_EQ(g.version(), held.graph_version);
  const uint32_t version = session.reconstructor()->deformation().version();
  EXPECT_EQ(version, held.deformation_version);
  // The checkpoint's frames and the logged ones after it.
  EXPECT_GT(session.trajectory().size(), held.trajectory.size());
  session.reconstructor()->map().for_each_chunk([&](const ChunkKey& key, const Chunk& c) {
    EXPECT_LE(c.version, version) << store::to_string(key);
  });
  Walk walk(&session);
  walk.sequence_ = held.next_sequence + 10;
  ASSERT_TRUE(walk.go(6, 12, 0.75)) << walk.last_problem;
  EXPECT_GE(walk.fused, walk.processed * 9 / 10) << walk.last_problem;
}

// The chunks of the scan file in a graph version older than `version` (the staged ones, which the
// pager evicted since the last checkpoint, included).
size_t stored_chunks_before(const std::string& path, uint32_t version, const PointMap* resident) {
  auto store = store::ScanStore::open(path, store::OpenMode::kReadOnly);
  EXPECT_TRUE(store) << store.status().to_string();
  if (!store) return 0;
  auto chunks = (*store)->list_chunks(/*include_staged=*/true);
  EXPECT_TRUE(chunks) << chunks.status().to_string();
  if (!chunks) return 0;
  size_t n = 0;
  for (const store::ChunkInfo& c : *chunks)
    n += c.version < version && c.point_count > 0 && (!resident || !resident->find(c.key));
  return n;
}

// A scan that ends after a closure, its map over a budget that evicts what the camera left
// behind: the chunks evicted before the correction are brought up to date too (moved, their
// surfaces merged), so the scan file ends with every chunk in the final version and an export
// needs to move nothing.
TEST(ScanEnd, EvictedChunksFollowTheLastCorrection) {
  const std::string dir = temp_dir("scan-end-evicted");
  AppConfig config = scan_config(dir, /*frame_log=*/false);
  config.fusion.evict_distance_m = 0.3;
  config.fusion.evict_min_age_frames = 5;
  config.fusion.memory_budget_mib = 0.3 + fusiond::MemoryBudget::of(config).frame_work_mib();
  const std::string path = dir + "/loop.dfscan";
  fusiond::SqliteCheckpointSink sink(config, fusiond::SqliteSinkOptions{path});
  fusiond::ScanSession session(config, sink);
  ASSERT_TRUE(session.start("loop").is_ok());
  Walk walk(&session);
  ASSERT_TRUE(walk.go(0, 1, 1) && walk.go(1, 45, 0.75) && walk.go(45, 2, 0.75)) << walk.last_problem;
  ASSERT_TRUE(walk.until_version_above(0, 2))
      << walk.last_problem << "; " << closure_stats(session);
  ASSERT_TRUE(walk.frame(2)) << walk.last_problem;
  const IncrementalReconstructor& r = *session.reconstructor();
  const uint32_t version = r.deformation().version();
  // What makes the case: chunks out of memory, stored before the correction.
  const size_t stale_evicted = stored_chunks_before(path, version, &r.map());
  ASSERT_GT(stale_evicted, 0u) << "the budget evicted no chunk stored before the correction";

  auto saved = session.stop("done", fusiond::FusionProgress{});
  ASSERT_TRUE(saved) << saved.status().to_string();
  EXPECT_TRUE(saved->store.is_ok()) << saved->store.to_string();
  EXPECT_EQ(stored_chunks_before(path, version, nullptr), 0u)
      << "of " << stale_evicted << " chunks evicted before the correction";
}

}  // namespace
}  // namespace depthfuse::testing
