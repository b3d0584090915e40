// The map follows the pose graph (MapDeformation): points move with their keyframes, a doubled
// surface merges, points crossing into a stale chunk move once, the lazy path within its budget,
// keyframes added after the graph's snapshot, and the history's memory.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>

#include "core_test_util.hpp"
#include "depthfuse/fusion.hpp"
#include "depthfuse/incremental.hpp"
#include "depthfuse/map_deformation.hpp"

using namespace depthfuse;

namespace {

Pose translation(double x, double y, double z) {
  Pose T = Pose::Identity();
  T.translation() = Eigen::Vector3d(x, y, z);
  return T;
}

// Frames fused at given poses into a map, each a frame id of its own.
struct Fusing {
  ReconstructionConfig config;
  PointMap map{0.5};
  Fuser fuser{config.sensor, config.fusion};
  MeasurementImage m;
  uint32_t next_frame = 1;

  void fuse(const Frame& f, const Pose& T_world_cam) {
    ASSERT_TRUE(backproject(f, config.sensor, config.fusion, &m).is_ok());
    fuser.fuse(m, nullptr, T_world_cam, next_frame++, &map);
  }
};

// The largest |z - z0| over the map's points.
double largest_offset_from_plane_z(const PointMap& map, double z0) {
  double worst = 0;
  map.for_each_chunk([&](const ChunkKey&, const Chunk& c) {
    for (const Eigen::Vector3f& p : c.points().position_m)
      worst = std::max(worst, std::abs(p.z() - z0));
  });
  return worst;
}

size_t points_off_plane_z(const PointMap& map, double z0, double tolerance_m) {
  size_t n = 0;
  map.for_each_chunk([&](const ChunkKey&, const Chunk& c) {
    for (const Eigen::Vector3f& p : c.points().position_m) n += std::abs(p.z() - z0) > tolerance_m;
  });
  return n;
}

bool all_chunks_at(const PointMap& map, uint32_t version) {
  bool all = true;
  map.for_each_chunk([&](const ChunkKey&, const Chunk& c) { all &= c.version == version; });
  return all;
}

// A point fused by `frame`; its colour carries `id` (a deformation moves it, nothing changes it).
PointRecord point_at(const Eigen::Vector3f& p, uint32_t frame, int id = 0) {
  PointRecord r;
  r.rgb[0] = static_cast<uint8_t>(id & 255);
  r.rgb[1] = static_cast<uint8_t>(id >> 8);
  r.position_m = p;
  r.normal = Eigen::Vector3f(0.6f, 0.0f, 0.8f);
  // An ellipsoid that is not aligned with the axes: its rotation shows.
  const Eigen::Matrix3f A =
      (Eigen::Matrix3f() << 3, 1, 0, 1, 2, 0.5f, 0, 0.5f, 4).finished() * 1e5f;
  r.information[0] = A(0, 0);
  r.information[1] = A(0, 1);
  r.information[2] = A(0, 2);
  r.information[3] = A(1, 1);
  r.information[4] = A(1, 2);
  r.information[5] = A(2, 2);
  r.last_frame = frame;
  return r;
}

int id_of(const PointArrays& a, size_t i) {
  return a.state[i].r | (a.state[i].g << 8);
}

// Every point of `original` once in `map`, moved by its keyframe's motion since version 0
// (position, normal and information, in double).
void expect_each_point_moved_once(const PointArrays& original, const PointMap& map,
                                  const MapDeformation& deformation) {
  const PointArrays after = map.gather();
  ASSERT_EQ(after.size(), original.size());
  std::vector<int> seen(original.size(), 0);
  for (size_t i = 0; i < after.size(); ++i) {
    const int j = id_of(after, i);
    ASSERT_LT(j, static_cast<int>(original.size()));
    ++seen[j];
    const uint32_t frame = original.state[j].last_frame;
    ASSERT_EQ(after.state[i].last_frame, frame);
    const Pose M = deformation.motion(frame, 0);
    const Eigen::Vector3d p = M * original.position_m[j].cast<double>();
    EXPECT_LT((after.position_m[i].cast<double>() - p).norm(), 1e-6) << "point " << j;
    const Eigen::Matrix3d R = M.linear();
    EXPECT_LT((after.normal(i).cast<double>() - R * original.normal(j).cast<double>()).norm(),
              1e-6);
    const Eigen::Matrix3d L = R * information_matrix(original, j).cast<double>() * R.transpose();
    EXPECT_LT((information_matrix(after, i).cast<double>() - L).norm(), 1e-6 * L.norm());
  }
  EXPECT_EQ(std::count(seen.begin(), seen.end(), 1), static_cast<long>(original.size()));
  // No point left behind in a chunk it is not in.
  map.for_each_chunk([&](const ChunkKey& k, const Chunk& c) {
    EXPECT_EQ(c.version, 1u);
    for (const Eigen::Vector3f& p : c.points().position_m) EXPECT_EQ(map.key_for(p), k);
  });
}

// Chunk a = (0, 0, 0) with points near its +x face, chunk b = (1, 0, 0) throughout, from two
// keyframes; a correction that moves a's points across into b.
struct CrossingScene {
  PointMap map{0.5};
  PointArrays original;
  MapDeformation deformation;
  const ChunkKey a{0, 0, 0}, b{1, 0, 0};

  CrossingScene() {
    for (int i = 0; i < 40; ++i)
      original.push_back(
          point_at({0.42f + 0.002f * i, 0.1f + 0.005f * i, 0.2f}, i % 2 ? 3 : 12, i));
    for (int i = 0; i < 40; ++i)
      original.push_back(
          point_at({0.55f + 0.01f * i, 0.2f, 0.3f + 0.002f * i}, i % 2 ? 5 : 15, 40 + i));
    map.add_points(original);
    EXPECT_EQ(map.chunk_count(), 2u);
    EXPECT_TRUE(deformation.keyframe_added(0, 1, Pose::Identity()).is_ok());
    EXPECT_TRUE(deformation.keyframe_added(1, 10, translation(1, 0, 0)).is_ok());
    Pose T0 = Pose::Identity();
    T0.linear() = Eigen::AngleAxisd(0.05, Eigen::Vector3d::UnitZ()).toRotationMatrix();
    T0.translation() = Eigen::Vector3d(0.12, 0.0, 0.01);
    EXPECT_TRUE(deformation.correct({T0, translation(1.1, 0.02, 0.0)}).is_ok());
  }
};

}  // namespace

// (a) Two views of a wall, the second fused at its keyframe's pose 5 cm off: the wall is doubled.
// The correction moves that keyframe back; afterwards the cloud is one layer on the plane, and the
// second view's points where the first view saw the wall too have merged into its points.
TEST(MapDeformation, ACorrectedKeyframeBringsItsWallBackAndTheDoubledSurfaceMerges) {
  Fusing fx;
  const double wall_z = 2.2;  // clear of the chunks' faces (every 0.5 m)
  const Pose T_a = Pose::Identity(), T_b = translation(0.4, 0, 0);
  const Pose T_b_drifted = translation(0.4, 0, 0.05);
  MapDeformation deformation;
  ASSERT_TRUE(deformation.keyframe_added(0, fx.next_frame, T_a).is_ok());
  fx.fuse(test::render_plane(T_a, Eigen::Vector3d::UnitZ(), wall_z), T_a);
  const size_t first_view = fx.map.point_count();
  ASSERT_TRUE(deformation.keyframe_added(1, fx.next_frame, T_b_drifted).is_ok());
  fx.fuse(test::render_plane(T_b, Eigen::Vector3d::UnitZ(), wall_z), T_b_drifted);
  const size_t second_view = fx.map.point_count() - first_view;
  // Doubled: the second view's wall lies 5 cm behind the first's.
  EXPECT_EQ(points_off_plane_z(fx.map, wall_z, 0.01), second_view);

  // The second view's points on the part of the wall the first view saw too (its footprint: the
  // image's extent at the wall's depth), once moved back.
  const CameraIntrinsics K = CameraIntrinsics::kinect_v2();
  const double half_w = wall_z * (K.width - 1 - K.cx) / K.fx,
               half_h = wall_z * (K.height - 1 - K.cy) / K.fy;
  size_t overlap = 0;
  fx.map.for_each_chunk([&](const ChunkKey&, const Chunk& c) {
    for (size_t i = 0; i < c.points().size(); ++i) {
      const Eigen::Vector3f& p = c.points().position_m[i];
      overlap +=
          c.points().state[i].last_frame == 2 && std::abs(p.x()) < half_w && std::abs(p.y()) < half_h;
    }
  });
  ASSERT_GT(overlap, second_view / 2);

  Result<uint32_t> v = deformation.correct({T_a, T_b});
  ASSERT_TRUE(v.is_ok()) << v.status().to_string();
  EXPECT_EQ(*v, 1u);
  const size_t before = fx.map.point_count();
  EXPECT_EQ(deformation.bring_all_up_to_date(&fx.map), before);  // every point brought up to date
  EXPECT_TRUE(all_chunks_at(fx.map, 1));
  EXPECT_EQ(fx.map.version(), 1u);

  EXPECT_LT(largest_offset_from_plane_z(fx.map, wall_z), 1.5e-3);
  const size_t merged = before - fx.map.point_count();
  EXPECT_EQ(merged, deformation.stats().points_merged);
  // About the overlap: a pair straddling a chunk's face is not merged (the pass is per chunk), a
  // point just outside the first view's footprint may merge with its edge, and the two views'
  // pixels do not pair one to one everywhere.
  EXPECT_GT(merged, overlap * 9 / 10) << "overlap " << overlap;
  EXPECT_LT(merged, overlap * 21 / 20) << "overlap " << overlap;
}

// Keyframes whose relation the correction does not change: the cloud moves rigidly, exactly, and
// nothing merges. (The merge rule would accept some pairs of young points of two keyframes, which
// fusion never compared: it compares a measurement with points, never two points. Merging them,
// 0.13 % of this wall, would thin the cloud at every closure.)
TEST(MapDeformation, ARigidMoveOfTheWholeMapMergesNothing) {
  Fusing fx;
  MapDeformation deformation;
  const double wall_z = 2.2;
  std::vector<Pose> keyframes;
  for (int k = 0; k < 4; ++k) {
    keyframes.push_back(translation(0.15 * k, 0.05 * k, 0));
    ASSERT_TRUE(deformation.keyframe_added(k, fx.next_frame, keyframes.back()).is_ok());
    for (int f = 0; f < 3; ++f) {
      const Pose T = translation(0.15 * k + 0.05 * f, 0.05 * k, 0.02 * f);
      fx.fuse(test::render_plane(T, Eigen::Vector3d::UnitZ(), wall_z), T);
    }
  }
  const size_t before = fx.map.point_count();
  // Fusion's product of Gaussians of differently tilted ellipsoids leaves the plane a little.
  const double offset = largest_offset_from_plane_z(fx.map, wall_z);
  std::vector<Pose> moved;
  const Pose shift = translation(0.01, -0.02, 0.03);
  for (const Pose& T : keyframes) moved.push_back(shift * T);
  ASSERT_TRUE(deformation.correct(moved).is_ok());
  EXPECT_EQ(deformation.bring_all_up_to_date(&fx.map), before);
  EXPECT_EQ(deformation.stats().points_merged, 0u);
  EXPECT_EQ(fx.map.point_count(), before - deformation.stats().points_merged);
  EXPECT_LT(largest_offset_from_plane_z(fx.map, wall_z + 0.03), offset + 1e-5);
}

// (b) Points that a correction moves into a chunk not yet up to date wait in its pending buffer
// and are moved once: the result is every point moved directly by its keyframe's motion.
TEST(MapDeformation, PointsCrossingIntoAStaleChunkWaitAndMoveOnce) {
  CrossingScene s;
  s.deformation.update(&s.map, {s.a});
  EXPECT_EQ(s.map.find(s.a)->version, 1u);
  EXPECT_EQ(s.map.find(s.b)->version, 0u);
  const size_t waiting = s.deformation.pending_points();
  EXPECT_GT(waiting, 20u);
  EXPECT_EQ(s.deformation.stats().points_pending, waiting);
  s.deformation.update(&s.map, {s.b});
  EXPECT_EQ(s.deformation.pending_points(), 0u);
  EXPECT_EQ(s.deformation.stats().points_updated, s.original.size());
  expect_each_point_moved_once(s.original, s.map, s.deformation);
}

// Points crossing into a chunk the pager evicted wait for it rather than start a new chunk at its
// key (which the pager would have to load the stored one into at once, over the budget).
TEST(MapDeformation, PointsCrossingIntoAnEvictedChunkWaitUntilItIsLoaded) {
  CrossingScene s;
  Chunk stored;
  s.map.extract(s.b, &stored);  // evicted, at version 0
  s.deformation.set_stored_elsewhere([&](const ChunkKey& k) { return k == s.b; });
  s.deformation.update(&s.map, {s.a});
  EXPECT_EQ(s.map.find(s.b), nullptr);
  EXPECT_EQ(s.deformation.pending_keys(), std::vector<ChunkKey>{s.b});
  EXPECT_GT(s.deformation.pending_points(), 20u);
  s.map.insert(s.b, std::move(stored));  // loaded back
  s.deformation.update(&s.map, {s.b});
  EXPECT_TRUE(s.deformation.pending_keys().empty());
  expect_each_point_moved_once(s.original, s.map, s.deformation);
}

// A checkpoint stores the points waiting for a chunk as they are (pending()); a resumed scan's
// deformation takes them back (restore_pending()) and moves them once, as if it had not stopped.
TEST(MapDeformation, PendingPointsStoredAndRestoredMoveOnceAfterAResume) {
  CrossingScene s;
  Chunk stored;
  s.map.extract(s.b, &stored);
  s.deformation.set_stored_elsewhere([&](const ChunkKey& k) { return k == s.b; });
  s.deformation.update(&s.map, {s.a});
  const std::vector<PendingPoints> pending = s.deformation.pending();
  ASSERT_EQ(pending.size(), 1u);
  EXPECT_EQ(pending[0].key, s.b);
  EXPECT_EQ(pending[0].version, 1u);
  EXPECT_EQ(pending[0].points.size(), s.deformation.pending_points());

  // The resumed process: the map as stored (a current, b evicted at version 0), the history and
  // the pending points.
  MapDeformation resumed;
  ASSERT_TRUE(resumed.restore(s.deformation.history()).is_ok());
  ASSERT_TRUE(resumed.restore_pending(pending).is_ok());
  EXPECT_EQ(resumed.pending_points(), pending[0].points.size());
  PointMap map(0.5);
  map.insert(s.a, Chunk(*s.map.find(s.a)));
  map.insert(s.b, std::move(stored));
  resumed.update(&map, {s.b});
  EXPECT_TRUE(resumed.pending_keys().empty());
  expect_each_point_moved_once(s.original, map, resumed);
}

// Points pending for a chunk that is neither in memory nor stored elsewhere (its stored row had no
// points) start the chunk when it is updated, rather than wait for ever.
TEST(MapDeformation, PendingPointsWithoutTheirChunkStartIt) {
  CrossingScene s;
  s.deformation.update(&s.map, {s.a});
  const std::vector<PendingPoints> pending = s.deformation.pending();
  ASSERT_EQ(pending.size(), 1u);
  MapDeformation resumed;
  ASSERT_TRUE(resumed.restore(s.deformation.history()).is_ok());
  ASSERT_TRUE(resumed.restore_pending(pending).is_ok());
  PointMap map(0.5);
  map.insert(s.a, Chunk(*s.map.find(s.a)));
  resumed.update(&map, resumed.pending_keys());
  ASSERT_NE(map.find(s.b), nullptr);
  EXPECT_EQ(map.find(s.b)->points().size(), pending[0].points.size());
  EXPECT_EQ(map.find(s.b)->version, resumed.version());
}

TEST(MapDeformation, PendingPointsOutsideTheHistoryAreRefused) {
  CrossingScene s;
  s.deformation.update(&s.map, {s.a});
  std::vector<PendingPoints> pending = s.deformation.pending();
  ASSERT_EQ(pending.size(), 1u);
  MapDeformation resumed;
  ASSERT_TRUE(resumed.restore(s.deformation.history()).is_ok());
  pending[0].version = 2;  // the history ends at 1
  Status st = resumed.restore_pending(pending);
  EXPECT_EQ(st.code(), StatusCode::kInvalidArgument);
  EXPECT_NE(st.message().find("points pending for chunk (1, 0, 0) at version 2: outside the history"),
            std::string::npos)
      << st.message();
  pending[0].version = 1;
  pending.push_back(pending[0]);
  st = resumed.restore_pending(pending);
  EXPECT_NE(st.message().find("given twice"), std::string::npos) << st.message();
  EXPECT_EQ(resumed.pending_points(), 0u);
}

// (c) The lazy path through process(): the frame's chunks follow before it is registered, the
// other chunks over the next frames, nearest first, within the per-frame budget.
TEST(MapDeformation, ProcessBringsTheViewUpToDateAndSweepsTheRestWithinItsBudget) {
  ReconstructionConfig c;
  c.fusion.deform_points_per_frame = 20000;
  IncrementalReconstructor rec(c);
  const double wall_z = 2.2;
  // A camera walking 5 m along a wall, a keyframe every fourth frame.
  std::vector<Pose> keyframes;
  for (int i = 0; i <= 20; ++i) {
    const Pose T = translation(0.25 * i, 0, 0);
    if (i % 4 == 0) {
      keyframes.push_back(T);
      ASSERT_TRUE(rec.deformation().keyframe_added(i / 4, rec.next_frame_id(), T).is_ok());
    }
    Frame f = test::render_plane(T, Eigen::Vector3d::UnitZ(), wall_z);
    f.T_world_cam_hint = T;
    ASSERT_TRUE(rec.process(f).is_ok());
  }
  // The loop closure: the whole walk was 2 cm too near the wall.
  const Pose shift = translation(0, 0, 0.02);
  std::vector<Pose> corrected;
  for (const Pose& T : keyframes) corrected.push_back(shift * T);
  ASSERT_TRUE(rec.deformation().correct(corrected).is_ok());

  // Where the walk ended: the chunks the camera sees are up to date before it is registered, the
  // start of the walk is not. (Registered against the wall where it was, whether the map or the
  // model rendered for the last frame, 2 cm from here, the frame would go 2 cm back.)
  const Pose end = translation(5, 0, 0);
  Frame f = test::render_plane(end, Eigen::Vector3d::UnitZ(), wall_z);
  f.T_world_cam_hint = shift * end;
  Result<FrameReport> first = rec.process(f);
  ASSERT_TRUE(first.is_ok());
  EXPECT_TRUE(first->registered);
  EXPECT_FALSE(first->model_reused);
  EXPECT_NEAR(first->T_world_cam.translation().z(), 0.02, 1e-3);
  size_t stale = 0, near_current = 0, stale_points = 0, largest_chunk = 0;
  rec.map().for_each_chunk([&](const ChunkKey& k, const Chunk& ch) {
    const double x = rec.map().chunk_origin_m(k).x();
    if (x > 4.0 && x < 6.0) {
      near_current += ch.version == 1;
      EXPECT_EQ(ch.version, 1u) << "chunk at x " << x;
    }
    stale += ch.version == 0;
    if (ch.version == 0) stale_points += ch.points().size();
    largest_chunk = std::max(largest_chunk, ch.points().size());
  });
  EXPECT_GT(near_current, 0u);
  EXPECT_GT(stale, 10u);
  // The rest over the next frames (the merge passes the view's chunks left, then the stale
  // chunks), never much more than the budget each: at most a chunk over.
  int frames = 0;
  while (rec.deformation().oldest_version() != 1) {
    Result<FrameReport> r = rec.process(f);
    ASSERT_TRUE(r.is_ok());
    EXPECT_GT(r->swept_points, 0u) << "frame " << frames;
    EXPECT_LT(r->swept_points, 20000u + largest_chunk) << "frame " << frames;
    ASSERT_LT(++frames, 100);
  }
  EXPECT_EQ(rec.deformation().pending_points(), 0u);
  EXPECT_TRUE(all_chunks_at(rec.map(), 1));
  EXPECT_GE(frames, static_cast<int>(stale_points / (20000 + largest_chunk)));
  EXPECT_LE(frames, static_cast<int>(rec.map().point_count() / 20000) + 2);
  // The wall moved 2 cm, all of it (the frames fused since merge into it and move its points a
  // little off the plane, as before: 0.1 mm).
  EXPECT_LT(largest_offset_from_plane_z(rec.map(), wall_z + 0.02), 1e-3);
}

// Registration moving the pose a little leaves the chunks around the view as they are; a jump
// (a relocalisation) brings those of the new view up to date before fusion.
TEST(MapDeformation, AFrameWhosePoseJumpsGetsItsNewViewUpToDate) {
  Fusing fx;
  MapDeformation d;
  ASSERT_TRUE(d.keyframe_added(0, fx.next_frame, Pose::Identity()).is_ok());
  for (int i = 0; i < 8; ++i) {
    const Pose T = translation(1.0 * i, 0, 0);
    fx.fuse(test::render_plane(T, Eigen::Vector3d::UnitZ(), 2.2), T);
  }
  ASSERT_TRUE(d.correct({translation(0, 0, 0.01)}).is_ok());
  const auto current_near = [&](double x0) {
    size_t n = 0, all = 0;
    fx.map.for_each_chunk([&](const ChunkKey& k, const Chunk& c) {
      const double x = fx.map.chunk_origin_m(k).x() + 0.25;
      if (std::abs(x - x0) < 0.75) {
        ++all;
        n += c.version == 1;
      }
    });
    return std::make_pair(n, all);
  };
  const Pose at_start = translation(0, 0, 0.01);
  MeasurementImage m;
  ASSERT_TRUE(backproject(test::render_plane(at_start, Eigen::Vector3d::UnitZ(), 2.21),
                          fx.config.sensor, fx.config.fusion, &m)
                  .is_ok());
  d.update_visible(&fx.map, m, at_start);
  auto [n0, all0] = current_near(0.0);
  EXPECT_EQ(n0, all0);
  EXPECT_GT(all0, 0u);
  const uint64_t chunks = d.stats().chunks_updated;
  // ICP moved the pose by a centimetre: nothing more to do.
  d.update_visible_if_moved(&fx.map, m, translation(0.01, 0, 0.01));
  EXPECT_EQ(d.stats().chunks_updated, chunks);
  // Relocalised 5 m on.
  d.update_visible_if_moved(&fx.map, m, translation(5.0, 0, 0.01));
  EXPECT_GT(d.stats().chunks_updated, chunks);
  auto [n5, all5] = current_near(5.0);
  EXPECT_EQ(n5, all5);
  EXPECT_GT(all5, 0u);
}

// (d) Keyframes the graph did not have when it was snapshotted move rigidly with the last one it
// had; one added after the correction is in its version already.
TEST(MapDeformation, KeyframesAddedAfterTheSnapshotRideWithTheLastCorrected) {
  MapDeformation d;
  const Pose T0 = Pose::Identity(), T1 = translation(1, 0, 0);
  Pose T2 = translation(2, 0.1, 0);
  T2.linear() = Eigen::AngleAxisd(0.3, Eigen::Vector3d::UnitY()).toRotationMatrix();
  ASSERT_TRUE(d.keyframe_added(0, 1, T0).is_ok());
  ASSERT_TRUE(d.keyframe_added(1, 10, T1).is_ok());
  ASSERT_TRUE(d.keyframe_added(2, 20, T2).is_ok());
  EXPECT_EQ(d.keyframe_of(0), 0u);
  EXPECT_EQ(d.keyframe_of(9), 0u);
  EXPECT_EQ(d.keyframe_of(10), 1u);
  EXPECT_EQ(d.keyframe_of(1000), 2u);
  // The graph knew keyframes 0 and 1.
  Pose T1c = translation(1.05, -0.02, 0);
  T1c.linear() = Eigen::AngleAxisd(0.02, Eigen::Vector3d::UnitZ()).toRotationMatrix();
  ASSERT_TRUE(d.correct({T0, T1c}).is_ok());
  const Pose ride = T1c * T1.inverse();
  EXPECT_TRUE(d.motion(25, 0).isApprox(ride, 1e-9));
  EXPECT_TRUE(d.motion(15, 0).isApprox(ride, 1e-9));
  EXPECT_TRUE(d.motion(5, 0).isApprox(Pose::Identity(), 1e-12));
  EXPECT_TRUE(d.history().T_world_kf.back()[2].isApprox(ride * T2, 1e-9));

  // Keyframe 3 joins in version 1; the next correction moves it.
  const Pose T3 = translation(3, 0, 0);
  ASSERT_TRUE(d.keyframe_added(3, 30, T3).is_ok());
  EXPECT_TRUE(d.motion(35, 1).isApprox(Pose::Identity(), 1e-12));
  const Pose T3c = translation(3, 0.04, 0);
  ASSERT_TRUE(d.correct({T0, T1c, ride * T2, T3c}).is_ok());
  EXPECT_TRUE(d.motion(35, 1).isApprox(T3c * T3.inverse(), 1e-9));
  // Points of keyframe 2 in a chunk of version 0 go the whole way: the ride, then nothing more.
  EXPECT_TRUE(d.motion(25, 0).isApprox(ride, 1e-9));

  // On points: a chunk of version 0 with keyframe 2's points moves by the ride.
  PointMap map(0.5);
  PointArrays pts;
  pts.push_back(point_at({2.1f, 0.2f, 1.1f}, 22));
  map.add_points(pts);
  d.bring_all_up_to_date(&map);
  const PointArrays out = map.gather();
  ASSERT_EQ(out.size(), 1u);
  EXPECT_LT((out.position_m[0].cast<double>() - ride * Eigen::Vector3d(2.1, 0.2, 1.1)).norm(),
            1e-5);
}

// (e) The history is kept only as far back as a chunk needs it: resident, pending, or stored out
// of memory. A chunk older than that cannot be moved, and says so.
TEST(MapDeformation, HistoryIsDroppedWhenNoChunkNeedsIt) {
  PointMap map(0.5);
  PointArrays pts;
  for (int i = 0; i < 10; ++i) pts.push_back(point_at({0.1f + 0.6f * i, 0.1f, 0.1f}, 1 + 10 * i));
  map.add_points(pts);
  MapDeformation d;
  std::vector<Pose> poses;
  for (int k = 0; k < 100; ++k) {
    poses.push_back(translation(0.06 * k, 0, 0));
    ASSERT_TRUE(d.keyframe_added(k, 1 + k, poses.back()).is_ok());
  }
  const auto correct_by = [&](double dz) {
    for (Pose& T : poses) T.translation().z() += dz;
    ASSERT_TRUE(d.correct(poses).is_ok());
  };
  correct_by(0.001);
  d.bring_all_up_to_date(&map);
  const size_t settled = d.memory_bytes();
  for (int i = 0; i < 30; ++i) {
    correct_by(0.001);
    d.bring_all_up_to_date(&map);
    EXPECT_EQ(d.oldest_version(), d.version());
  }
  EXPECT_EQ(d.version(), 31u);
  EXPECT_LT(d.memory_bytes(), settled + 1024);

  // A chunk stored out of memory at version 31 keeps that version's poses while others follow.
  Chunk stored;
  ASSERT_TRUE(map.extract(map.key_for(Eigen::Vector3f(0.1f, 0.1f, 0.1f)), &stored));
  d.set_oldest_stored_version(stored.version);
  for (int i = 0; i < 5; ++i) {
    correct_by(0.001);
    d.bring_all_up_to_date(&map);
  }
  EXPECT_EQ(d.oldest_version(), 31u);
  EXPECT_GT(d.memory_bytes(), settled + 5 * 100 * 48);
  // It comes back and follows: it moved 5 mm since.
  map.insert(map.key_for(stored.points().position_m[0]), stored);
  d.set_oldest_stored_version(std::nullopt);
  d.bring_all_up_to_date(&map);
  EXPECT_EQ(d.oldest_version(), d.version());
  EXPECT_LT(d.memory_bytes(), settled + 1024);
  const PointArrays all = map.gather();
  for (size_t i = 0; i < all.size(); ++i) EXPECT_NEAR(all.position_m[i].z(), 0.1 + 0.036, 1e-5);
  EXPECT_EQ(d.stats().points_unmovable, 0u);

  // A chunk older than the history kept stays where it is, counted.
  Chunk old;
  old.points_for_write().push_back(point_at({5.2f, 0.1f, 0.1f}, 3));
  old.version = 2;
  map.insert({10, 0, 0}, old);
  d.bring_all_up_to_date(&map);
  EXPECT_EQ(d.stats().points_unmovable, 1u);
  EXPECT_EQ(map.find({10, 0, 0})->version, d.version());
  EXPECT_EQ(map.find({10, 0, 0})->points().position_m[0], Eigen::Vector3f(5.2f, 0.1f, 0.1f));
}

TEST(MapDeformation, BadInputIsRefusedWithTheReason) {
  MapDeformation d;
  Status s = d.keyframe_added(1, 1, Pose::Identity());
  EXPECT_FALSE(s.is_ok());
  EXPECT_NE(s.message().find("keyframe 1 added out of order: the next keyframe is 0"),
            std::string::npos)
      << s.message();
  ASSERT_TRUE(d.keyframe_added(0, 5, Pose::Identity()).is_ok());
  s = d.keyframe_added(1, 5, Pose::Identity());
  EXPECT_NE(s.message().find("first frame 5 is not after keyframe 0's (5)"), std::string::npos)
      << s.message();
  Pose bent = Pose::Identity();
  bent.linear()(0, 0) = 2;
  s = d.keyframe_added(1, 6, bent);
  EXPECT_NE(s.message().find("keyframe 1's pose is not a rotation and a translation"),
            std::string::npos)
      << s.message();
  Result<uint32_t> r = d.correct({Pose::Identity(), Pose::Identity()});
  ASSERT_FALSE(r.is_ok());
  EXPECT_NE(r.status().message().find("a correction of 2 keyframes, but only 1 were added"),
            std::string::npos)
      << r.status().message();
  EXPECT_FALSE(d.correct({}).is_ok());
  EXPECT_EQ(d.version(), 0u);

  DeformationHistory h = d.history();
  h.max_motion_m.push_back(0.0);
  s = d.restore(h);
  EXPECT_NE(s.message().find("1 versions of poses but 2 motion bounds"), std::string::npos)
      << s.message();
  h = d.history();
  h.merges.push_back({ChunkKey{1, 2, 3}, 0, 1});  // version 1 does not exist yet
  s = d.restore(h);
  EXPECT_NE(s.message().find("the merge pass queued for chunk (1, 2, 3) counts from version 1, "
                             "outside the history kept"),
            std::string::npos)
      << s.message();
  ASSERT_TRUE(d.restore(d.history()).is_ok());
  EXPECT_EQ(d.keyframe_count(), 1u);
}
