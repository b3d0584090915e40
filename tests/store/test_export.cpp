// The offline tools on real scan files: export (PLY and PCD, read back by depthfuse, Open3D and
// PCL, filters, during a live writer), inspect and export on damaged files, refine.
#include <cstring>
#include <gtest/gtest.h>
#include <signal.h>
#include <sys/wait.h>
#include <unistd.h>

#include <chrono>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <random>
#include <thread>

#include "depthfuse/pipeline.hpp"
#include "depthfuse/trajectory.hpp"
#include "depthfuse/ply.hpp"
#include "depthfuse/store/export.hpp"
#include "depthfuse/store/scan_recorder.hpp"
#include "depthfuse/store/scan_store.hpp"
#include "store_test_util.hpp"

using namespace depthfuse;
using namespace depthfuse::store;
using test::make_points;
using test::Proc;
using test::run;
using test::TempDir;

namespace {

std::string cli() { return DEPTHFUSE_CLI; }

// A scan file with `chunks` chunks of random points (merges 0..9 so that filters bite).
PointArrays make_scan(const std::string& path, int chunks, size_t points_each = 300) {
  auto s = ScanStore::open(path, OpenMode::kCreate);
  EXPECT_TRUE(s);
  PointArrays all;
  EXPECT_TRUE((*s)->begin_checkpoint());
  for (int i = 0; i < chunks; ++i) {
    const ChunkKey k{i % 7 - 3, i / 7 - 2, i % 3};
    Chunk c;
    c.points_for_write() = make_points(k, static_cast<uint32_t>(i + 1), points_each);
    for (size_t j = 0; j < c.points().size(); ++j) c.points_for_write().state[j].merges = static_cast<uint16_t>(j % 10);
    EXPECT_TRUE((*s)->write_chunk(k, c));
  }
  CheckpointInfo info;
  info.last_frame_id = 1;
  EXPECT_TRUE((*s)->commit_checkpoint(info));
  // In key order, as export streams them.
  auto st = (*s)->for_each_chunk([&](const ChunkInfo&, PointArrays& a) {
    all.append(a);
    return Status::ok();
  });
  EXPECT_TRUE(st);
  return all;
}

void write_reference(const std::string& path, const PointArrays& a) {
  std::FILE* f = std::fopen(path.c_str(), "w");
  for (size_t i = 0; i < a.size(); ++i)
    std::fprintf(f, "%.9g %.9g %.9g %.9g %.9g %.9g %d %d %d\n", a.position_m[i].x(), a.position_m[i].y(), a.position_m[i].z(), a.state[i].nx, a.state[i].ny,
                 a.state[i].nz, a.state[i].r, a.state[i].g, a.state[i].b);
  std::fclose(f);
}

bool has_open3d() { return run("/usr/bin/python3 -c 'import open3d'").code == 0; }

// Open3D reads the cloud; positions, normals and colours equal the reference.
Proc open3d_check(const std::string& cloud, const std::string& reference) {
  const std::string script =
      "import sys, numpy as np, open3d as o3d\n"
      "pc = o3d.io.read_point_cloud(sys.argv[1])\n"
      "ref = np.loadtxt(sys.argv[2], ndmin=2)\n"
      "p, n, c = np.asarray(pc.points), np.asarray(pc.normals), np.asarray(pc.colors)\n"
      "assert len(p) == len(ref), (len(p), len(ref))\n"
      "assert pc.has_normals() and pc.has_colors()\n"
      "assert np.array_equal(p.astype(np.float32), ref[:, 0:3].astype(np.float32)), 'positions'\n"
      "assert np.array_equal(n.astype(np.float32), ref[:, 3:6].astype(np.float32)), 'normals'\n"
      "assert np.abs(c * 255 - ref[:, 6:9]).max() < 1e-3, 'colours'\n"
      "print('open3d ok', len(p))\n";
  const std::string py = cloud + ".check.py";
  std::ofstream(py) << script;
  return run("/usr/bin/python3 " + py + " " + cloud + " " + reference);
}

}  // namespace

TEST(Export, PlyAndPcdHoldEveryPointExactly) {
  TempDir dir;
  const std::string scan = dir.file("scan.db");
  const PointArrays all = make_scan(scan, 40);
  const std::string reference = dir.file("reference.txt");
  write_reference(reference, all);
  for (const char* ext : {"ply", "pcd"}) {
    const std::string out = dir.file(std::string("cloud.") + ext);
    const Proc r = run(cli() + " export " + scan + " -o " + out);
    ASSERT_EQ(r.code, 0) << r.output;
    EXPECT_NE(r.output.find("wrote " + std::to_string(all.size()) + " points from 40 chunks"), std::string::npos)
        << r.output;
    if (std::string(ext) == "ply") {
      auto back = read_ply(out);
      ASSERT_TRUE(back) << back.status().to_string();
      ASSERT_EQ(back->size(), all.size());
      EXPECT_TRUE(test::same_bits(back->position_m, all.position_m));
      for (size_t i = 0; i < all.size(); ++i) {
        ASSERT_EQ(std::memcmp(&back->state[i].nz, &all.state[i].nz, sizeof(float)), 0) << i;
        ASSERT_EQ(back->state[i].r, all.state[i].r) << i;
      }
    }
#ifdef DEPTHFUSE_PCL_READ_CHECK
    const Proc pcl = run(std::string(DEPTHFUSE_PCL_READ_CHECK) + " " + out + " " + reference);
    EXPECT_EQ(pcl.code, 0) << ext << ": " << pcl.output;
    EXPECT_NE(pcl.output.find("ok " + std::to_string(all.size())), std::string::npos) << pcl.output;
#else
    ADD_FAILURE() << "PCL was not found at build time; the PCL read check did not run";
#endif
    if (has_open3d()) {
      const Proc o3d = open3d_check(out, reference);
      EXPECT_EQ(o3d.code, 0) << ext << ": " << o3d.output;
    } else {
      ADD_FAILURE() << "/usr/bin/python3 has no open3d (python3-open3d)";
    }
  }
}

TEST(Export, FiltersKeepExactlyTheSelectedPoints) {
  TempDir dir;
  const std::string scan = dir.file("scan.db");
  const PointArrays all = make_scan(scan, 40);
  const Eigen::AlignedBox3f box(Eigen::Vector3f(-0.7f, -0.6f, 0.1f), Eigen::Vector3f(0.9f, 0.4f, 1.2f));
  PointArrays want;
  for (size_t i = 0; i < all.size(); ++i)
    if (all.state[i].merges >= 4 && box.contains(all.position(i))) want.push_back(all.get(i));
  ASSERT_GT(want.size(), 100u);
  ASSERT_LT(want.size(), all.size() / 2);
  const std::string out = dir.file("filtered.pcd"), reference = dir.file("filtered.txt");
  const Proc r = run(cli() + " export " + scan + " -o " + out + " --min-merges 4 --bbox -0.7,-0.6,0.1,0.9,0.4,1.2");
  ASSERT_EQ(r.code, 0) << r.output;
  write_reference(reference, want);
#ifdef DEPTHFUSE_PCL_READ_CHECK
  const Proc pcl = run(std::string(DEPTHFUSE_PCL_READ_CHECK) + " " + out + " " + reference);
  EXPECT_EQ(pcl.code, 0) << pcl.output;
#endif
  // The library call agrees, and bad options are refused with a reason.
  auto s = ScanStore::open(scan, OpenMode::kReadOnly);
  ASSERT_TRUE(s);
  ExportOptions o;
  o.min_merges = 4;
  o.bbox_m = box;
  auto rep = export_cloud(**s, dir.file("lib.ply"), o);
  ASSERT_TRUE(rep) << rep.status().to_string();
  EXPECT_EQ(rep->points_written, want.size());
  EXPECT_NE(run(cli() + " export " + scan + " -o x.ply --bbox 1,2,3").output.find("six comma-separated"), std::string::npos);
  EXPECT_NE(run(cli() + " export " + scan + " -o x.xyz").output.find(".ply or .pcd"), std::string::npos);
  EXPECT_EQ(run(cli() + " export " + scan + " -o x.ply --min-merges lots").code, 2);  // a bad option
}

TEST(Export, DamagedFilesGetClearErrorsFromInspectAndExport) {
  TempDir dir;
  const std::string good = dir.file("good.db");
  make_scan(good, 30);
  const Proc ok = run(cli() + " inspect " + good);
  ASSERT_EQ(ok.code, 0) << ok.output;
  EXPECT_NE(ok.output.find("integrity      ok"), std::string::npos) << ok.output;
  EXPECT_NE(ok.output.find("schema version " + std::to_string(kSchemaVersion)), std::string::npos) << ok.output;
  EXPECT_NE(ok.output.find("in 30 chunks"), std::string::npos) << ok.output;

  // A flipped byte inside one chunk's blob.
  const std::string flipped = dir.file("flipped.db");
  std::filesystem::copy_file(good, flipped);
  {
    std::ifstream in(flipped, std::ios::binary);
    std::string bytes((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
    const size_t at = bytes.find("DFB1", bytes.find("DFB1") + 1);
    ASSERT_NE(at, std::string::npos);
    test::flip_byte(flipped, static_cast<long>(at + 200));
  }
  Proc r = run(cli() + " inspect " + flipped);
  EXPECT_EQ(r.code, 1) << r.output;
  EXPECT_NE(r.output.find("DAMAGED"), std::string::npos) << r.output;
  EXPECT_NE(r.output.find("chunk ("), std::string::npos) << r.output;
  const std::string out = dir.file("out.ply");
  r = run(cli() + " export " + flipped + " -o " + out);
  EXPECT_EQ(r.code, 1) << r.output;
  EXPECT_NE(r.output.find("chunk ("), std::string::npos) << r.output;
  EXPECT_FALSE(std::filesystem::exists(out)) << "a partial export was left behind";
  r = run(cli() + " export " + flipped + " -o " + out + " --skip-damaged");
  EXPECT_EQ(r.code, 1) << r.output;
  EXPECT_NE(r.output.find("1 damaged chunks were left out"), std::string::npos) << r.output;
  EXPECT_TRUE(std::filesystem::exists(out));

  // Truncated, garbage, empty, missing.
  const std::string cut = dir.file("cut.db");
  std::filesystem::copy_file(good, cut);
  std::filesystem::resize_file(cut, std::filesystem::file_size(cut) * 2 / 3);
  const std::string garbage = dir.file("garbage.db");
  {
    std::ofstream g(garbage, std::ios::binary);
    for (int i = 0; i < 5000; ++i) g.put(static_cast<char>(i * 7));
  }
  struct Case {
    std::string file, expect;
  };
  for (const Case& c : {Case{cut, "truncated"}, Case{garbage, "not a scan file"},
                        Case{dir.file("missing.db"), "no such scan file"}}) {
    for (const std::string& cmd : {cli() + " inspect " + c.file, cli() + " export " + c.file + " -o " + out + "2.ply"}) {
      r = run(cmd);
      EXPECT_EQ(r.code, 1) << cmd << "\n" << r.output;
      EXPECT_NE(r.output.find(c.expect), std::string::npos) << cmd << "\n" << r.output;
    }
  }
}

// Poses carry a checksum like chunks: one flipped bit in a stored pose is named by inspect, and
// export --trajectory fails instead of writing the wrong pose.
TEST(Export, AFlippedBitInAStoredPoseIsNamedAndStopsTheExport) {
  TempDir dir;
  const std::string scan = dir.file("poses.db");
  auto pose_of = [](uint32_t f) {
    Pose T = Pose::Identity();
    T.translation() = Eigen::Vector3d(0.6 + 0.01 * f, -0.2, 1.5);
    return T;
  };
  {
    auto s = ScanStore::open(scan, OpenMode::kCreate);
    ASSERT_TRUE(s);
    ASSERT_TRUE((*s)->begin_checkpoint());
    const ChunkKey k{0, 0, 0};
    Chunk c;
    c.points_for_write() = make_points(k, 1, 100);
    ASSERT_TRUE((*s)->write_chunk(k, c));
    for (uint32_t f = 1; f <= 10; ++f) {
      PoseRecord p;
      p.frame_id = f;
      p.utime = 1000000 * f;
      p.T_world_cam = pose_of(f);
      ASSERT_TRUE((*s)->write_pose(p));
    }
    CheckpointInfo info;
    info.last_frame_id = 10;
    info.frames_fused = 10;
    ASSERT_TRUE((*s)->commit_checkpoint(info));
  }
  Proc r = run(cli() + " inspect " + scan);
  ASSERT_EQ(r.code, 0) << r.output;
  EXPECT_NE(r.output.find("10 pose records checksummed"), std::string::npos) << r.output;
  EXPECT_EQ(r.output.find("unchecked"), std::string::npos) << r.output;

  // One bit of frame 7's x translation (the low bytes of a double: the pose stays a valid pose).
  {
    std::ifstream in(scan, std::ios::binary);
    const std::string bytes((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
    const std::vector<uint8_t> blob = encode_pose(pose_of(7));
    const size_t at = bytes.find(std::string(blob.begin(), blob.end()));
    ASSERT_NE(at, std::string::npos);
    std::fstream f(scan, std::ios::binary | std::ios::in | std::ios::out);
    f.seekp(static_cast<std::streamoff>(at + 3 * sizeof(double) + 1));
    f.put(static_cast<char>(bytes[at + 3 * sizeof(double) + 1] ^ 0x10));
  }
  r = run(cli() + " inspect " + scan);
  EXPECT_EQ(r.code, 1) << r.output;
  EXPECT_NE(r.output.find("pose of frame 7: checksum mismatch"), std::string::npos) << r.output;
  const std::string out = dir.file("out.ply"), traj = dir.file("traj.txt");
  r = run(cli() + " export " + scan + " -o " + out + " --trajectory " + traj);
  EXPECT_EQ(r.code, 1) << r.output;
  EXPECT_NE(r.output.find("pose of frame 7: checksum mismatch"), std::string::npos) << r.output;
  EXPECT_FALSE(std::filesystem::exists(traj));
  EXPECT_FALSE(std::filesystem::exists(out));
}

TEST(Export, WorksWhileAWriterIsCheckpointing) {
  TempDir dir;
  const std::string scan = dir.file("scan.db");
  make_scan(scan, 10, 100);
  const pid_t child = fork();
  ASSERT_GE(child, 0);
  if (child == 0) {
    // The "daemon": a checkpoint every few ms, each rewriting 30 chunks with new point counts.
    auto s = ScanStore::open(scan, OpenMode::kReadWrite);
    if (!s) _exit(3);
    for (uint32_t n = 2;; ++n) {
      if (!(*s)->begin_checkpoint()) _exit(4);
      for (int i = 0; i < 30; ++i) {
        const ChunkKey k{i, static_cast<int32_t>(n % 3), 0};
        Chunk c;
        c.points_for_write() = make_points(k, n, 50 + (n * 13 + i * 7) % 300);
        if (!(*s)->write_chunk(k, c)) _exit(5);
      }
      CheckpointInfo info;
      info.last_frame_id = n;
      if (!(*s)->commit_checkpoint(info)) _exit(6);
    }
  }
  std::vector<uint64_t> exported;
  for (int i = 0; i < 8; ++i) {
    std::this_thread::sleep_for(std::chrono::milliseconds(30));
    const std::string out = dir.file("live-" + std::to_string(i) + ".pcd");
    const Proc r = run(cli() + " export " + scan + " -o " + out);
    EXPECT_EQ(r.code, 0) << r.output;
    unsigned long long n = 0;
    EXPECT_EQ(std::sscanf(r.output.c_str(), "wrote %llu points", &n), 1) << r.output;
    exported.push_back(n);
  }
  kill(child, SIGKILL);
  waitpid(child, nullptr, 0);
  // Every export is exactly one checkpoint's cloud.
  auto s = ScanStore::open(scan, OpenMode::kReadOnly);
  ASSERT_TRUE(s);
  auto cps = (*s)->checkpoints();
  ASSERT_TRUE(cps);
  EXPECT_GT(cps->size(), 10u);
  for (uint64_t n : exported) {
    const bool matches = std::any_of(cps->begin(), cps->end(), [&](const CheckpointRecord& c) { return c.point_count == n; });
    EXPECT_TRUE(matches) << n << " points is no checkpoint's cloud";
  }
}

namespace {

// A short scan through the recorder whose keyframe poses are perturbed (as drifted tracking
// would leave them): refine must bring them back towards the truth.
struct RefineScene {
  std::vector<Pose> truth;  // per keyframe
};

RefineScene make_refinable_scan(const std::string& path) {
  RefineScene scene;
  test::Corridor corridor;
  corridor.length_m = 8.0;
  const int n = 40;
  RecorderConfig rc;
  rc.bounded_memory = false;
  rc.keyframe_every_n_frames = 2;
  ScanMetadata meta;
  meta.method = "full";
  auto recorder = ScanRecorder::create(path, meta, "", "", rc);
  EXPECT_TRUE(recorder) << recorder.status().to_string();
  ReconstructionConfig config;
  config = config.with_method(Method::kYlimaki17);  // fused with the drifted poses as given
  IncrementalReconstructor rec(config);
  std::mt19937 rng(3);
  std::normal_distribution<double> noise(0.0, 0.01);
  for (int i = 0; i < n; ++i) {
    const Pose truth = corridor.pose(i, n);
    Frame f = corridor.render(truth, test::small_camera(), static_cast<uint32_t>(i));
    Pose drifted = truth;
    drifted.translation() += Eigen::Vector3d(noise(rng), noise(rng), noise(rng));
    f.T_world_cam_hint = drifted;
    auto rep = rec.process(f);
    EXPECT_TRUE(rep);
    EXPECT_TRUE((*recorder)->record_frame(f, *rep, &rec.map()));
    if (i % 2 == 0) scene.truth.push_back(truth);
  }
  EXPECT_TRUE((*recorder)->finish(&rec.map()));
  return scene;
}

// The keyframes' position error after the best rigid alignment to the truth (the ATE): refinement
// may move the whole trajectory rigidly (its gauge), and the first keyframe is as wrong as any.
double mean_error_m(const std::string& path, const std::vector<Pose>& truth) {
  auto s = ScanStore::open(path, OpenMode::kReadOnly);
  EXPECT_TRUE(s);
  auto kfs = (*s)->list_keyframes();
  EXPECT_TRUE(kfs);
  EXPECT_EQ(kfs->size(), truth.size());
  std::vector<Pose> estimate;
  for (const auto& kf : *kfs) estimate.push_back(kf.T_world_cam);
  estimate.resize(std::min(estimate.size(), truth.size()));
  auto ate = absolute_trajectory_error(estimate, std::vector<Pose>(truth.begin(), truth.begin() + estimate.size()));
  EXPECT_TRUE(ate);
  return ate ? ate->rmse_m : 0.0;
}


}  // namespace

TEST(Refine, ReRegistersTheKeyframesAndWritesACheckpoint) {
  TempDir dir;
  const std::string scan = dir.file("scan.db");
  const RefineScene scene = make_refinable_scan(scan);
  const double before = mean_error_m(scan, scene.truth);
  uint64_t points_before = 0;
  {
    auto s = ScanStore::open(scan, OpenMode::kReadOnly);
    ASSERT_TRUE(s);
    points_before = (*(*s)->last_checkpoint())->point_count;
  }
  // The scan's camera has 1/16 of a Kinect's pixels: ICP's default of 500 pairs is more than its
  // sampled pixels give on most keyframes, which would then keep their poses (9 of 20 registered).
  const std::string config = dir.file("small_camera.toml");
  std::ofstream(config) << "[registration]\nmin_correspondences = 100\n";
  // --out leaves the original alone.
  const std::string copy = dir.file("refined.db");
  Proc r = run(cli() + " refine " + scan + " --iterations 3 --config " + config + " --out " + copy);
  ASSERT_EQ(r.code, 0) << r.output;
  // Every keyframe was re-registered in each of the three rounds, and the report says so.
  size_t all_registered = 0;
  for (size_t at = r.output.find("registered 20/20 frames"); at != std::string::npos;
       at = r.output.find("registered 20/20 frames", at + 1))
    ++all_registered;
  EXPECT_EQ(all_registered, 3u) << r.output;
  EXPECT_EQ(mean_error_m(scan, scene.truth), before);
  const double after = mean_error_m(copy, scene.truth);
  std::printf("keyframe pose error (ATE): %.2f mm before, %.2f mm after refine\n",
              before * 1000, after * 1000);
  EXPECT_LT(after, 0.7 * before);
  // In place: one new checkpoint, the cloud replaced, the file intact.
  r = run(cli() + " refine " + scan + " --iterations 3 --config " + config);
  ASSERT_EQ(r.code, 0) << r.output;
  auto s = ScanStore::open(scan, OpenMode::kReadOnly);
  ASSERT_TRUE(s);
  auto last = (*s)->last_checkpoint();
  ASSERT_TRUE(last && *last);
  EXPECT_EQ((*last)->reason, "refine");
  EXPECT_NE((*last)->point_count, points_before);
  auto integrity = (*s)->integrity_check();
  ASSERT_TRUE(integrity);
  EXPECT_TRUE(integrity->ok());
  EXPECT_NEAR(mean_error_m(scan, scene.truth), after, 1e-9);
  // A scan being written by someone else is refused, not corrupted.
  auto writer = ScanStore::open(scan, OpenMode::kReadWrite);
  ASSERT_TRUE(writer);
  r = run(cli() + " refine " + scan);
  EXPECT_EQ(r.code, 1);
  EXPECT_NE(r.output.find("another process is writing"), std::string::npos) << r.output;
}

namespace {

// A pose graph of one keyframe (from frame 1; the frames before belong to it too) that one
// correction moved from the identity to `moved`: version 1.
GraphCheckpoint one_keyframe_moved(const Pose& moved) {
  GraphCheckpoint g;
  GraphKeyframe k;
  k.frame_id = 1;
  k.T_world_kf = moved;
  k.cloud = std::make_shared<const KeyframeCloud>();
  g.graph.keyframes.push_back(k);
  g.graph.version = 1;
  g.deformation.keyframe_first_frame = {1};
  g.deformation.oldest_version = 0;
  g.deformation.T_world_kf = {{Pose::Identity()}, {moved}};
  g.deformation.max_motion_m = {0.0, moved.translation().norm()};
  return g;
}

}  // namespace

// A chunk stored before the last loop closure's correction reached it (evicted stale, or the scan
// ended first) is exported where the correction put its keyframe, not where it was fused.
TEST(Export, AChunkStoredBeforeACorrectionIsExportedWhereItsKeyframeMoved) {
  TempDir dir;
  const std::string scan = dir.file("stale.db");
  const ChunkKey key{0, 0, 0};
  Chunk chunk;
  chunk.points_for_write() = make_points(key, 1, 100);  // fused by frame 0: keyframe 0's segment
  chunk.version = 0;
  Pose moved = Pose::Identity();
  moved.translation() = Eigen::Vector3d(0.05, 0.0, 0.0);
  {
    auto s = ScanStore::open(scan, OpenMode::kCreate);
    ASSERT_TRUE(s);
    ASSERT_TRUE((*s)->begin_checkpoint());
    ASSERT_TRUE((*s)->write_chunk(key, chunk));
    ASSERT_TRUE((*s)->write_graph(one_keyframe_moved(moved)));
    ASSERT_TRUE((*s)->commit_checkpoint(CheckpointInfo{}));
  }
  auto s = ScanStore::open(scan, OpenMode::kReadOnly);
  ASSERT_TRUE(s);
  const std::string out = dir.file("out.ply");
  ASSERT_TRUE(export_cloud(**s, out, ExportOptions{}));
  auto cloud = read_ply(out);
  ASSERT_TRUE(cloud) << cloud.status().to_string();
  ASSERT_EQ(cloud->size(), chunk.points().size());
  for (size_t i = 0; i < cloud->size(); ++i)
    EXPECT_LT((cloud->position_m[i] - chunk.points().position_m[i] - Eigen::Vector3f(0.05f, 0, 0)).norm(), 1e-5f)
        << "point " << i;
}

// Points a correction moved into a chunk that had not followed it yet are stored as they are
// (chunk_pending), each with the version it was moved to: read back exactly, replaced whole by the
// next checkpoint, checked by inspect, and exported where the graph's current version puts them.
TEST(Export, PointsPendingForAChunkAreStoredAndExportedWhereTheirKeyframeMoved) {
  TempDir dir;
  const std::string scan = dir.file("pending.db");
  const ChunkKey key{0, 0, 0}, waiting{1, 0, 0};
  Chunk chunk;
  chunk.points_for_write() = make_points(key, 1, 50);
  Pose moved = Pose::Identity();
  moved.translation() = Eigen::Vector3d(0.05, 0.0, 0.0);
  // Pending from version 0 (moved by the correction to version 1 when exported) and from version 1.
  const std::vector<PendingPoints> pending = {{waiting, 0, make_points(waiting, 2, 30)},
                                              {waiting, 1, make_points(waiting, 3, 20)}};
  auto s = ScanStore::open(scan, OpenMode::kCreate);
  ASSERT_TRUE(s);
  ASSERT_TRUE((*s)->begin_checkpoint());
  ASSERT_TRUE((*s)->write_chunk(key, chunk));
  ASSERT_TRUE((*s)->write_graph(one_keyframe_moved(moved)));
  ASSERT_TRUE((*s)->write_pending(pending));
  ASSERT_TRUE((*s)->commit_checkpoint(CheckpointInfo{}));

  auto read = (*s)->read_pending();
  ASSERT_TRUE(read) << read.status().to_string();
  ASSERT_EQ(read->size(), 2u);
  for (size_t i = 0; i < 2; ++i) {
    EXPECT_EQ((*read)[i].key, waiting);
    EXPECT_EQ((*read)[i].version, pending[i].version);
    ASSERT_EQ((*read)[i].points.size(), pending[i].points.size());
    for (size_t j = 0; j < pending[i].points.size(); ++j)
      ASSERT_EQ((*read)[i].points.position_m[j], pending[i].points.position_m[j]);
  }
  auto integrity = (*s)->integrity_check();
  ASSERT_TRUE(integrity);
  EXPECT_TRUE(integrity->ok()) << integrity->problems.front();
  EXPECT_EQ(integrity->pending_rows_checked, 2u);
  auto summary = (*s)->summary();
  ASSERT_TRUE(summary);
  EXPECT_EQ(summary->pending_rows, 2u);
  EXPECT_EQ(summary->pending_points, 50u);

  const std::string out = dir.file("out.ply");
  ASSERT_TRUE(export_cloud(**s, out, ExportOptions{}));
  auto cloud = read_ply(out);
  ASSERT_TRUE(cloud) << cloud.status().to_string();
  ASSERT_EQ(cloud->size(), 100u);
  // The chunk's points first, then the pending ones by key and version; those stored at version 0
  // moved with keyframe 0.
  const Eigen::Vector3f shift(0.05f, 0, 0);
  for (size_t i = 0; i < 50; ++i)
    EXPECT_LT((cloud->position_m[i] - chunk.points().position_m[i] - shift).norm(), 1e-5f);
  for (size_t i = 0; i < 30; ++i)
    EXPECT_LT((cloud->position_m[50 + i] - pending[0].points.position_m[i] - shift).norm(), 1e-5f);
  for (size_t i = 0; i < 20; ++i)
    EXPECT_LT((cloud->position_m[80 + i] - pending[1].points.position_m[i]).norm(), 1e-6f);

  // A damaged row is named by inspect and stops the export.
  const std::string damaged = dir.file("damaged.db");
  ASSERT_TRUE((*s)->copy_to(damaged));
  test::exec_sql(damaged, "UPDATE chunk_pending SET point_count = point_count + 1 WHERE version = 1;");
  const std::string what = "points pending for chunk (1,0,0) at version 1: checksum mismatch";
  Proc r = run(cli() + " inspect " + damaged);
  EXPECT_EQ(r.code, 1) << r.output;
  EXPECT_NE(r.output.find(what), std::string::npos) << r.output;
  r = run(cli() + " export " + damaged + " -o " + dir.file("damaged.ply"));
  EXPECT_EQ(r.code, 1) << r.output;
  EXPECT_NE(r.output.find(what), std::string::npos) << r.output;
  // A row whose checksum was taken away is damage too: every such row is written with one.
  const std::string unchecked = dir.file("unchecked.db");
  ASSERT_TRUE((*s)->copy_to(unchecked));
  test::exec_sql(unchecked, "UPDATE chunk_pending SET checksum = NULL WHERE version = 0;");
  r = run(cli() + " inspect " + unchecked);
  EXPECT_EQ(r.code, 1) << r.output;
  EXPECT_NE(r.output.find("points pending for chunk (1,0,0) at version 0: no checksum"),
            std::string::npos)
      << r.output;

  // The next checkpoint replaces them: here the chunk followed and nothing waits any more.
  ASSERT_TRUE((*s)->begin_checkpoint());
  ASSERT_TRUE((*s)->write_pending(std::vector<PendingPoints>{}));
  ASSERT_TRUE((*s)->commit_checkpoint(CheckpointInfo{}));
  read = (*s)->read_pending();
  ASSERT_TRUE(read);
  EXPECT_TRUE(read->empty());
}
