// The map following the pose graph after a loop closure (MapDeformation) on a fused room: 8 x 6 m
// walls 2.5 m high and the floor, points as fusion leaves them (1 mm along the normal, 2 mm
// across), seen on two laps of 100 keyframes each (a point's keyframe by its angle around the
// room's centre, its lap at random). A correction moves the second lap's keyframes by up to 2 cm
// and 0.2 degrees, the first lap's a tenth of that.
//  - BM_BringAllUpToDate/N/rigid: the whole map of N points, ns per point (moving, crossing into
//    other chunks, the merge pass); rigid = 1: every keyframe by the same motion, so that the
//    merge pass skips every chunk (moving alone);
//  - BM_MergePass/N: the merge pass alone on one chunk holding a doubled wall of N points (two
//    visits 0.5 mm apart), ns per point;
//  - BM_Sweep/N: what one frame's sweep costs at the default budget (fusion.
//    deform_points_per_frame), ms, on the map of N points (the first frame after a correction
//    lists the stale chunks too);
//  - BM_FirstFrameAfterClosure/N: update_visible() for the first frame after a closure, which
//    moves the chunks around its view (their merge passes wait for the sweep), ms;
//  - BM_UpdateVisible/v/N: what a frame pays before registration once every chunk is up to date,
//    on the map of N points: v = 0 before any correction (nothing), v = 1 after one.
#include <benchmark/benchmark.h>

#include <cmath>
#include <map>
#include <memory>
#include <random>

#include "chunk_merge.hpp"
#include "depthfuse/config.hpp"
#include "depthfuse/map_deformation.hpp"

using namespace depthfuse;

namespace {

constexpr int kKeyframesPerLap = 100;
constexpr uint32_t kFramesPerKeyframe = 10;

Pose keyframe_pose(int k) {
  const double a = 2 * M_PI * (k % kKeyframesPerLap) / kKeyframesPerLap;
  Pose T = Pose::Identity();
  T.linear() = Eigen::AngleAxisd(a, Eigen::Vector3d::UnitZ()).toRotationMatrix();
  T.translation() = Eigen::Vector3d(1.5 * std::cos(a), 1.2 * std::sin(a), 1.3);
  return T;
}

// A fused point on a surface with normal n: 1 mm along it, 2 mm across.
PointState fused_state(const Eigen::Vector3f& n, uint32_t frame) {
  const Eigen::Vector3f t1 = n.unitOrthogonal(), t2 = n.cross(t1);
  const Eigen::Matrix3f L = n * n.transpose() / (1e-3f * 1e-3f) +
                            (t1 * t1.transpose() + t2 * t2.transpose()) / (2e-3f * 2e-3f);
  PointState s{};
  s.info_xx = L(0, 0);
  s.info_xy = L(0, 1);
  s.info_xz = L(0, 2);
  s.info_yy = L(1, 1);
  s.info_yz = L(1, 2);
  s.info_zz = L(2, 2);
  s.nx = n.x();
  s.ny = n.y();
  s.nz = n.z();
  s.merges = 10;
  s.last_frame = frame;
  return s;
}

struct Room {
  PointMap map{0.5};
  MapDeformation deformation;
  std::vector<Pose> keyframes;
  int corrections = 0;

  explicit Room(size_t points) {
    for (int k = 0; k < 2 * kKeyframesPerLap; ++k) {
      keyframes.push_back(keyframe_pose(k));
      (void)deformation.keyframe_added(k, 1 + kFramesPerKeyframe * k, keyframes.back());
    }
    std::mt19937 rng(7);
    std::uniform_real_distribution<float> jitter(-0.2f, 0.2f);
    std::uniform_int_distribution<int> lap(0, 1), frame(0, kFramesPerKeyframe - 1);
    const float area = 2 * (8 + 6) * 2.5f + 8 * 6;
    const float s = std::sqrt(area / static_cast<float>(points));
    PointArrays all;
    const auto add = [&](const Eigen::Vector3f& p, const Eigen::Vector3f& n) {
      const double a = std::atan2(p.y(), p.x()) + (p.y() < 0 ? 2 * M_PI : 0);
      const int k =
          lap(rng) * kKeyframesPerLap +
          std::min(kKeyframesPerLap - 1, static_cast<int>(a / (2 * M_PI) * kKeyframesPerLap));
      all.push_back(p, fused_state(n, 1 + kFramesPerKeyframe * k + frame(rng)));
    };
    // Walls x = +-4, y = +-3, z in [0, 2.5]; the floor z = 0.
    for (float z = 0.5f * s; z < 2.5f; z += s)
      for (float u = -4; u < 4; u += s)
        for (int side : {-1, 1}) {
          add({u + jitter(rng) * s, side * 3.0f, z + jitter(rng) * s}, {0, -side * 1.0f, 0});
          if (std::abs(u) < 3)
            add({side * 4.0f, u + jitter(rng) * s, z + jitter(rng) * s}, {-side * 1.0f, 0, 0});
        }
    for (float x = -4 + 0.5f * s; x < 4; x += s)
      for (float y = -3 + 0.5f * s; y < 3; y += s)
        add({x + jitter(rng) * s, y + jitter(rng) * s, 0}, {0, 0, 1});
    map.add_points(all);
  }

  // A loop closure: the second lap's keyframes up to 2 cm and 0.2 degrees, the first's a tenth,
  // alternately one way and back so that the room stays where it is. Rigid: every keyframe by
  // the same motion (the merge pass finds nothing to do: what moving alone costs).
  void correct(bool rigid = false) {
    const double sign = (corrections++ % 2) ? -1 : 1;
    for (int k = 0; k < static_cast<int>(keyframes.size()); ++k) {
      const double f = rigid ? sign
                             : sign * (k < kKeyframesPerLap ? 0.1 : 1.0) *
                                   std::sin(M_PI * (k % kKeyframesPerLap) / kKeyframesPerLap);
      Pose M = Pose::Identity();
      M.linear() =
          Eigen::AngleAxisd(f * 0.2 * M_PI / 180, Eigen::Vector3d::UnitZ()).toRotationMatrix();
      M.translation() = Eigen::Vector3d(0.02 * f, -0.01 * f, 0.005 * f);
      keyframes[k] = M * keyframes[k];
    }
    (void)deformation.correct(keyframes);
  }
};

Room& room(size_t points) {
  static std::map<size_t, std::unique_ptr<Room>> rooms;
  auto& r = rooms[points];
  if (!r) r = std::make_unique<Room>(points);
  return *r;
}

// ns per point: the iteration's time over `points` (a rate, inverted).
benchmark::Counter ns_per_point(size_t points) {
  return benchmark::Counter(
      static_cast<double>(points) * 1e-9,
      benchmark::Counter::kIsIterationInvariantRate | benchmark::Counter::kInvert);
}

void BM_BringAllUpToDate(benchmark::State& state) {
  Room& r = room(static_cast<size_t>(state.range(0)));
  const size_t points = r.map.point_count();
  for (auto _ : state) {
    state.PauseTiming();
    r.correct(state.range(1) != 0);
    state.ResumeTiming();
    benchmark::DoNotOptimize(r.deformation.bring_all_up_to_date(&r.map));
  }
  state.counters["points"] = static_cast<double>(points);
  state.counters["ns_per_point"] = ns_per_point(points);
  state.counters["merged"] = static_cast<double>(r.deformation.stats().points_merged);
}

void BM_MergePass(benchmark::State& state) {
  // A 0.5 m chunk of wall seen on two visits: two layers 0.5 mm apart, each point a pixel's
  // footprint from its neighbours (4 mm), fresh (a single measurement's ellipsoid: 4 mm across,
  // 6 mm along the ray). About every point finds its partner.
  const size_t n = static_cast<size_t>(state.range(0));
  std::mt19937 rng(3);
  std::uniform_real_distribution<float> uniform(0.0f, 0.5f);
  PointArrays chunk;
  std::vector<uint32_t> segment;
  const Eigen::Vector3f normal(0, 0, -1);
  for (size_t i = 0; i < n; ++i) {
    const int visit = static_cast<int>(i % 2);
    PointState s = fused_state(normal, 1 + 100 * visit);
    const Eigen::Matrix3f L = Eigen::Vector3f(1 / 16e-6f, 1 / 16e-6f, 1 / 36e-6f).asDiagonal();
    s.info_xx = L(0, 0);
    s.info_xy = 0;
    s.info_xz = 0;
    s.info_yy = L(1, 1);
    s.info_yz = 0;
    s.info_zz = L(2, 2);
    s.merges = 0;
    chunk.push_back(Eigen::Vector3f(uniform(rng), uniform(rng), 0.25f + 0.0005f * visit), s);
    segment.push_back(visit);
  }
  // The two visits' keyframes moved apart: every pair across them is a candidate.
  struct : PairGate {
    bool moved_apart(uint32_t, uint32_t, const Eigen::Vector3f&) override { return true; }
  } apart;
  ChunkMerger merger;
  size_t merged = 0;
  for (auto _ : state) {
    state.PauseTiming();
    PointArrays a = chunk;
    std::vector<uint32_t> seg = segment;
    state.ResumeTiming();
    merged = merger.merge(&a, 0, &seg, &apart);
    benchmark::DoNotOptimize(a.position_m.data());
  }
  state.counters["merged_share"] = static_cast<double>(merged) / static_cast<double>(n);
  state.counters["ns_per_point"] = ns_per_point(n);
}

void BM_Sweep(benchmark::State& state) {
  Room& r = room(static_cast<size_t>(state.range(0)));
  const size_t budget = static_cast<size_t>(FusionConfig().deform_points_per_frame);
  const Eigen::Vector3d camera(1.5, 0, 1.3);
  size_t frames = 0, sweeps = 0;
  r.deformation.bring_all_up_to_date(&r.map);
  for (auto _ : state) {
    if (r.deformation.oldest_version() == r.deformation.version()) {  // the last sweep is done
      state.PauseTiming();
      r.correct();
      ++sweeps;
      state.ResumeTiming();
    }
    benchmark::DoNotOptimize(r.deformation.sweep(&r.map, camera, budget));
    ++frames;
  }
  state.counters["budget"] = static_cast<double>(budget);
  state.counters["frames_per_sweep"] = static_cast<double>(frames) / std::max<size_t>(1, sweeps);
}

// A camera 1.5 m from the room's +x wall, looking at it.
void wall_view(MeasurementImage* out, Pose* T_world_cam) {
  MeasurementImage& m = *out;
  m.intrinsics = CameraIntrinsics::kinect_v2();
  m.resize(m.intrinsics.width, m.intrinsics.height);
  for (int v = 0; v < m.height; ++v)
    for (int u = 0; u < m.width; ++u) {
      const size_t i = static_cast<size_t>(v) * m.width + u;
      m.z[i] = 1.5f;
      m.x[i] = static_cast<float>((u - m.intrinsics.cx) / m.intrinsics.fx) * m.z[i];
      m.y[i] = static_cast<float>((v - m.intrinsics.cy) / m.intrinsics.fy) * m.z[i];
      m.valid[i] = 1;
    }
  Pose& T = *T_world_cam;
  T = Pose::Identity();
  T.linear() << 0, 0, 1, -1, 0, 0, 0, -1, 0;  // camera z along +x, y down
  T.translation() = Eigen::Vector3d(2.5, 0.2, 1.2);
}

void BM_UpdateVisible(benchmark::State& state) {
  Room& r = room(static_cast<size_t>(state.range(1)));
  if (r.deformation.version() == 0) r.correct();
  r.deformation.bring_all_up_to_date(&r.map);
  MapDeformation before_any;  // version 0
  MapDeformation& d = state.range(0) > 0 ? r.deformation : before_any;
  MeasurementImage m;
  Pose T;
  wall_view(&m, &T);
  for (auto _ : state) d.update_visible(&r.map, m, T);
}

// The first frame after a closure: every chunk around the view is stale.
void BM_FirstFrameAfterClosure(benchmark::State& state) {
  Room& r = room(static_cast<size_t>(state.range(0)));
  MeasurementImage m;
  Pose T;
  wall_view(&m, &T);
  uint64_t moved = 0;
  for (auto _ : state) {
    state.PauseTiming();
    r.deformation.bring_all_up_to_date(&r.map);
    r.correct();
    const uint64_t before = r.deformation.stats().points_updated;
    state.ResumeTiming();
    r.deformation.update_visible(&r.map, m, T);
    moved += r.deformation.stats().points_updated - before;
  }
  state.counters["points_moved"] =
      benchmark::Counter(static_cast<double>(moved), benchmark::Counter::kAvgIterations);
}

}  // namespace

BENCHMARK(BM_BringAllUpToDate)
    ->Args({500000, 0})
    ->Args({2000000, 0})
    ->Args({2000000, 1})
    ->Unit(benchmark::kMillisecond)
    ->Iterations(4);
BENCHMARK(BM_MergePass)->Arg(20000)->Arg(60000)->Unit(benchmark::kMillisecond);
BENCHMARK(BM_Sweep)->Arg(500000)->Arg(2000000)->Unit(benchmark::kMillisecond);
BENCHMARK(BM_FirstFrameAfterClosure)->Arg(500000)->Arg(2000000)->Unit(benchmark::kMillisecond);
BENCHMARK(BM_UpdateVisible)
    ->Args({0, 2000000})
    ->Args({1, 500000})
    ->Args({1, 2000000})
    ->Unit(benchmark::kMicrosecond);
BENCHMARK_MAIN();
