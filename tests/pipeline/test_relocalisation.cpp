// Relocalisation (issue 19): frames without pose hints, tracked frame by frame as the fusion daemon
// does, over the synthetic corner. The camera is carried away (teleported to a view of unmapped
// floor), then brought back near where the scan began, far from the last pose fused: the frames
// away must be reported lost and not fused, and the camera must be found again among the
// keyframes instead of being tracked into a second copy of the corner.
#include <gtest/gtest.h>

#include <cmath>
#include <cstdio>

#include "depthfuse/pipeline.hpp"
#include "depthfuse/synthetic/synthetic_sequence.hpp"

using namespace depthfuse;

namespace {

constexpr int kLoopFrames = 300;  // the live benchmark's loop
constexpr int kStride = 3;        // every 3rd frame: 2.3 cm and 0.9 degree apart
constexpr int kAway = 3;          // frames while the camera is elsewhere
constexpr int kReturnAt = 15;     // where it comes back: 12 cm from the first keyframe
constexpr int kReturnFrames = 10;

struct Outcome {
  std::vector<FrameReport> away, back;
  int refused = 0;  // places found that the camera cannot have reached in the time
  size_t points_before_away = 0, points_after_away = 0, points_end = 0;
  std::vector<double> back_error_m;  // from the truth, in the first camera's frame
};

// The camera is away from `away_s` after the last frame of the loop on, and back `back_s` after
// it: a relocalisation needs the time to have got there (RelocalisationConfig::max_speed_m_s).
Outcome run(const synthetic::SyntheticSequence& seq, bool relocalise, double away_s = 1.0,
            double back_s = 5.0) {
  ReconstructionConfig c;
  c.relocalisation.enabled = relocalise;
  IncrementalReconstructor rec(c);
  Outcome out;
  auto process = [&](Frame f) {
    f.T_world_cam_hint.reset();  // as from a Kinect: the reconstructor tracks
    auto r = rec.process(f);
    EXPECT_TRUE(r.is_ok()) << r.status().to_string();
    return r.is_ok() ? *r : FrameReport{};
  };
  int64_t last_utime = 0;
  for (int i = 0; i < kLoopFrames; i += kStride) {
    const Frame f = seq.render(static_cast<size_t>(i));
    last_utime = f.utime;
    const FrameReport r = process(f);
    EXPECT_NE(r.tracking, TrackingState::kLost) << "frame " << i;
  }
  const auto after = [&](double s, int k) {
    return last_utime + static_cast<int64_t>(s * 1e6) + k * 100000;  // 10 Hz
  };
  out.points_before_away = rec.map().point_count();
  // Carried off to look down at the floor beyond the corner, where the map has nothing.
  const Pose away = synthetic::look_at({3.2, 3.2, 1.2}, {4.5, 4.5, 0.0});
  for (int k = 0; k < kAway; ++k) {
    Frame f = seq.render(0);
    seq.renderer().render(away, 1000 + k, true, &f.depth, &f.color);
    f.utime = after(away_s, k);
    out.away.push_back(process(f));
  }
  out.points_after_away = rec.map().point_count();
  const Pose T_0_world = seq.T_world_cam_true(0).inverse();  // tracking starts at the identity
  for (int k = 0; k < kReturnFrames; ++k) {
    const size_t i = static_cast<size_t>(kReturnAt + k * kStride);
    Frame f = seq.render(i);
    f.utime = after(back_s, k);
    out.back.push_back(process(f));
    out.refused += out.back.back().relocalisations_out_of_reach;
    const Pose truth = T_0_world * seq.T_world_cam_true(i);
    out.back_error_m.push_back((out.back.back().T_world_cam.translation() - truth.translation()).norm());
  }
  out.points_end = rec.map().point_count();
  return out;
}

}  // namespace

TEST(Relocalisation, ALostCameraIsReportedAndFoundAgainWhenItComesBack) {
  synthetic::SyntheticConfig sc;
  sc.frames = kLoopFrames;
  auto seq = synthetic::SyntheticSequence::create(sc);
  ASSERT_TRUE(seq.is_ok()) << seq.status().to_string();

  for (const bool relocalise : {true, false}) {
    SCOPED_TRACE(relocalise ? "relocalisation on" : "relocalisation off");
    const Outcome r = run(*seq, relocalise);
    // Away: lost, not fused, not relocalised (there is nothing to find).
    for (const FrameReport& f : r.away) {
      EXPECT_EQ(f.tracking, TrackingState::kLost);
      EXPECT_FALSE(f.fused());
      EXPECT_FALSE(f.relocalised);
    }
    EXPECT_EQ(r.points_after_away, r.points_before_away);

    int found = -1;
    for (size_t k = 0; k < r.back.size(); ++k) {
      const FrameReport& f = r.back[k];
      std::printf("back %zu: %s%s, fitness %.3f, %.1f mm from the truth, search %.1f ms\n", k,
                  to_string(f.tracking), f.relocalised ? " (relocalised)" : "",
                  f.registration.fitness, r.back_error_m[k] * 1e3, f.relocalisation_ms);
      if (found < 0 && f.relocalised) found = static_cast<int>(k);
    }
    std::printf("points: %zu before away, %zu at the end\n", r.points_before_away, r.points_end);
    if (relocalise) {
      ASSERT_GE(found, 0) << "not relocalised within " << kReturnFrames << " frames";
      for (int k = 0; k < found; ++k) EXPECT_FALSE(r.back[k].fused()) << "back " << k;
      for (size_t k = static_cast<size_t>(found); k < r.back.size(); ++k) {
        EXPECT_TRUE(r.back[k].fused()) << "back " << k;
        EXPECT_LT(r.back_error_m[k], 0.005) << "back " << k;
      }
      // Back in mapped space: the frames add little, no second copy of the corner.
      EXPECT_LT(r.points_end, r.points_before_away * 102 / 100);
    } else {
      // Without it the camera is not found where it is: every frame back is lost, or fused in
      // the wrong place.
      EXPECT_LT(found, 0);
      for (size_t k = 0; k < r.back.size(); ++k)
        EXPECT_TRUE(!r.back[k].fused() || r.back_error_m[k] > 0.05) << "back " << k;
    }
  }
}

// Found again where the camera cannot have got to in the time lost (back 0.1 s after the last frame
// fused, 2.4 m away): refused, and not fused there; once enough time has passed, found.
TEST(Relocalisation, APlaceTheCameraCannotHaveReachedInTheTimeLostIsRefused) {
  synthetic::SyntheticConfig sc;
  sc.frames = kLoopFrames;
  auto seq = synthetic::SyntheticSequence::create(sc);
  ASSERT_TRUE(seq.is_ok()) << seq.status().to_string();
  const Outcome soon = run(*seq, true, 0.033, 0.066);
  EXPECT_GT(soon.refused, 0);
  // The return frames come 0.1 s apart: the reach grows by 0.15 m a frame, and the first ones
  // are refused.
  ASSERT_FALSE(soon.back.empty());
  EXPECT_FALSE(soon.back[0].relocalised);
  EXPECT_FALSE(soon.back[0].fused());
  int found = -1;
  for (size_t k = 0; k < soon.back.size(); ++k)
    if (found < 0 && soon.back[k].relocalised) found = static_cast<int>(k);
  for (int k = 0; k < (found < 0 ? static_cast<int>(soon.back.size()) : found); ++k)
    EXPECT_FALSE(soon.back[k].fused()) << "back " << k;
  const Outcome later = run(*seq, true);
  EXPECT_EQ(later.refused, 0);
}

// Two rooms alike (the `rooms` scene's grid), both mapped from the same heading: a lost frame that
// fits both is not placed in either. The camera walks east through room (1,0) into room (2,0),
// is carried off to look at the floor, and comes back at a view of room (2,0) that room (1,0)
// shows as well. Without the rival test the search takes the first place verified.
TEST(Relocalisation, AViewThatFitsTwoMappedPlacesIsRefused) {
  synthetic::SyntheticConfig sc;
  sc.scene = synthetic::SceneKind::kRooms;
  sc.frames = 1;
  auto seq = synthetic::SyntheticSequence::create(sc);
  ASSERT_TRUE(seq.is_ok()) << seq.status().to_string();
  // Eye 1.5 m high, heading east, 20 degrees down, along the middle of the rooms' row.
  const auto at = [](double x_m) {
    return synthetic::look_at({x_m, 2.5, 1.5}, {x_m + 1.0, 2.5, 1.5 - std::tan(20.0 * M_PI / 180.0)});
  };
  constexpr double kStepM = 0.025;  // 0.75 m/s
  constexpr int kWalk = 300;  // from x = 6 m to 13.5 m: room (1,0), the doorway, room (2,0)
  const Frame tmpl = seq->render(0);
  const auto frame_at = [&](const Pose& T, int64_t utime, uint64_t key) {
    Frame f = tmpl;
    seq->renderer().render(T, key, true, &f.depth, &f.color);
    f.utime = utime;
    f.T_world_cam_hint.reset();
    return f;
  };
  for (const int rivals : {3, 0}) {
    SCOPED_TRACE(rivals > 0 ? "rival test on" : "rival test off");
    ReconstructionConfig c;
    c.relocalisation.ambiguity_rivals = rivals;
    IncrementalReconstructor rec(c);
    int64_t utime = 0;
    for (int i = 0; i < kWalk; ++i, utime += 33333) {
      auto r = rec.process(frame_at(at(6.0 + kStepM * i), utime, static_cast<uint64_t>(i)));
      ASSERT_TRUE(r.is_ok()) << r.status().to_string();
      ASSERT_NE(r->tracking, TrackingState::kLost) << "frame " << i;
    }
    const size_t points = rec.map().point_count();
    // Carried off: looking straight down at the floor, which matches nothing in particular.
    auto away = rec.process(frame_at(synthetic::look_at({12.5, 2.5, 1.2}, {12.5, 2.6, 0.0}),
                                     utime += 1000000, 5000));
    ASSERT_TRUE(away.is_ok());
    ASSERT_EQ(away->tracking, TrackingState::kLost);
    // Back 10 s later (every place mapped is within reach) at room (2,0)'s twin of x = 7.6 m.
    int ambiguous = 0, relocalised = 0;
    for (int k = 0; k < 3; ++k) {
      auto r = rec.process(frame_at(at(12.6 + kStepM * k), utime += 10000000, 6000 + k));
      ASSERT_TRUE(r.is_ok());
      ambiguous += r->relocalisations_ambiguous;
      relocalised += r->relocalised ? 1 : 0;
      if (rivals > 0) {
        EXPECT_FALSE(r->fused()) << "back " << k;
      }
    }
    std::printf("rivals %d: %d relocalised, %d refused as ambiguous\n", rivals, relocalised, ambiguous);
    if (rivals > 0) {
      EXPECT_EQ(relocalised, 0);
      EXPECT_GT(ambiguous, 0);
      EXPECT_EQ(rec.map().point_count(), points);
    } else {
      EXPECT_GT(relocalised, 0);  // the test can fail: without rivals a place is taken
    }
  }
}
