// Per-stage timings on the synthetic corner at Kinect V2 resolution, with a map that already holds
// the previous frames (the steady state of a scan).
#include <benchmark/benchmark.h>

#include <algorithm>

#include "depthfuse/fusion.hpp"
#include "depthfuse/measurement.hpp"
#include "depthfuse/registration.hpp"
#include "depthfuse/synthetic/synthetic_sequence.hpp"

using namespace depthfuse;

namespace {

struct Scan {
  synthetic::SyntheticSequence seq;
  ReconstructionConfig config;
  std::vector<Frame> frames;
  PointMap map{0.5};

  static Scan& get() {
    static Scan* s = [] {
      synthetic::SyntheticConfig c;
      c.frames = 30;
      auto seq = synthetic::SyntheticSequence::create(c);
      auto* scan = new Scan{std::move(*seq), {}, {}, PointMap(0.5)};
      for (size_t i = 0; i < scan->seq.size(); ++i) scan->frames.push_back(scan->seq.render(i));
      // The map of the first 20 frames: a scan in progress.
      Fuser fuser(scan->config.sensor, scan->config.fusion);
      MeasurementImage m;
      for (size_t i = 0; i < 20; ++i) {
        (void)backproject(scan->frames[i], scan->config.sensor, scan->config.fusion, &m);
        prefilter(scan->config.prefilter, &m);
        fuser.fuse(m, nullptr, scan->seq.T_world_cam_true(i), static_cast<uint32_t>(i + 1), &scan->map);
      }
      return scan;
    }();
    return *s;
  }

  // The steady-state frames 20-29, back-projected (and pre-filtered if asked): what each
  // iteration of a fusion benchmark cycles over.
  static constexpr size_t kSteadyFrames = 10;
  std::vector<MeasurementImage> steady_frames(const FusionConfig& fc, bool prefiltered) const {
    std::vector<MeasurementImage> ms(kSteadyFrames);
    for (size_t k = 0; k < ms.size(); ++k) {
      (void)backproject(frames[20 + k], config.sensor, fc, &ms[k]);
      if (prefiltered) prefilter(config.prefilter, &ms[k]);
    }
    return ms;
  }
};

void BM_Backproject(benchmark::State& state) {
  Scan& s = Scan::get();
  MeasurementImage m;
  FusionConfig fc = s.config.fusion;
  fc.threads = 1;
  for (auto _ : state) (void)backproject(s.frames[20], s.config.sensor, fc, &m);
}

void BM_Prefilter(benchmark::State& state) {
  Scan& s = Scan::get();
  MeasurementImage m0, m;
  (void)backproject(s.frames[20], s.config.sensor, s.config.fusion, &m0);
  for (auto _ : state) {
    state.PauseTiming();
    m = m0;
    state.ResumeTiming();
    benchmark::DoNotOptimize(prefilter(s.config.prefilter, &m));
  }
}

// Steady state of a scan: every iteration fuses the next frame (cycling over frames 20-29) into
// one growing map that already holds the first 20 frames.
void BM_Fuse(benchmark::State& state) {
  Scan& s = Scan::get();
  FusionConfig fc = s.config.fusion;
  fc.threads = static_cast<int>(state.range(0));
  const std::vector<MeasurementImage> ms = s.steady_frames(fc, true);
  PointMap map = s.map;
  Fuser fuser(s.config.sensor, fc);
  uint32_t id = 100;
  size_t k = 0;
  FusionStats total;
  for (auto _ : state) {
    const FusionStats st = fuser.fuse(ms[k], nullptr, s.seq.T_world_cam_true(20 + k), id++, &map);
    total.measurements += st.measurements;
    total.merged += st.merged;
    total.added += st.added;
    total.redundant += st.redundant;
    total.violations += st.violations;
    k = (k + 1) % ms.size();
  }
  state.counters["map_points"] = static_cast<double>(map.point_count());
  // What became of the measurements: the per-frame work depends on the mix.
  const double n = std::max<double>(1.0, static_cast<double>(total.measurements));
  state.counters["merged_pct"] = 100.0 * static_cast<double>(total.merged) / n;
  state.counters["added_pct"] = 100.0 * static_cast<double>(total.added) / n;
  state.counters["redundant_pct"] = 100.0 * static_cast<double>(total.redundant) / n;
}

// The one-core target: pre-filter plus fusion of a frame that is already back-projected.
// Each iteration starts from a fresh copy of the back-projected frame (not timed).
void BM_PrefilterPlusFusion(benchmark::State& state) {
  Scan& s = Scan::get();
  FusionConfig fc = s.config.fusion;
  fc.threads = static_cast<int>(state.range(0));
  const std::vector<MeasurementImage> ms = s.steady_frames(fc, false);
  MeasurementImage m;
  PointMap map = s.map;
  Fuser fuser(s.config.sensor, fc);
  uint32_t id = 100;
  size_t k = 0;
  for (auto _ : state) {
    state.PauseTiming();
    m = ms[k];
    state.ResumeTiming();
    prefilter(s.config.prefilter, &m, fc.threads);
    benchmark::DoNotOptimize(fuser.fuse(m, nullptr, s.seq.T_world_cam_true(20 + k), id++, &map));
    k = (k + 1) % ms.size();
  }
  state.counters["map_points"] = static_cast<double>(map.point_count());
}

// The whole per-frame fusion path: back-projection, normals, pre-filter, fusion.
void BM_FramePath(benchmark::State& state) {
  Scan& s = Scan::get();
  MeasurementImage m;
  PointMap map = s.map;
  FusionConfig fc = s.config.fusion;
  fc.threads = static_cast<int>(state.range(0));
  Fuser fuser(s.config.sensor, fc);
  uint32_t id = 100;
  size_t k = 0;
  for (auto _ : state) {
    (void)backproject(s.frames[20 + k], s.config.sensor, fc, &m);
    prefilter(s.config.prefilter, &m, fc.threads);
    benchmark::DoNotOptimize(fuser.fuse(m, nullptr, s.seq.T_world_cam_true(20 + k), id++, &map));
    k = (k + 1) % Scan::kSteadyFrames;
  }
  state.counters["map_points"] = static_cast<double>(map.point_count());
}

// Both registration benchmarks' case: frame 20 back-projected and pre-filtered, its start 2 cm
// off the true pose, and the registration settings with `threads`.
RegistrationConfig registration_case(const Scan& s, int threads, MeasurementImage* m, Pose* initial) {
  (void)backproject(s.frames[20], s.config.sensor, s.config.fusion, m);
  prefilter(s.config.prefilter, m);
  *initial = s.seq.T_world_cam_true(20);
  initial->translation() += Eigen::Vector3d(0.02, -0.01, 0.01);
  RegistrationConfig rc = s.config.registration;
  rc.threads = threads;
  return rc;
}

void BM_Reregistration(benchmark::State& state) {
  Scan& s = Scan::get();
  MeasurementImage m;
  Pose initial;
  Registrar reg(registration_case(s, static_cast<int>(state.range(0)), &m, &initial));
  for (auto _ : state) benchmark::DoNotOptimize(reg.refine(m, s.map, initial));
}

// The live path without a hint: coarse-to-fine tracking from a start 2 cm off, the map rendered
// at the start pose (Registrar::track), as the fusion daemon tracks a Kinect's frame.
void BM_Tracking(benchmark::State& state) {
  Scan& s = Scan::get();
  MeasurementImage m;
  Pose initial;
  Registrar reg(registration_case(s, static_cast<int>(state.range(0)), &m, &initial));
  for (auto _ : state) benchmark::DoNotOptimize(reg.track(m, s.map, initial, initial));
}

}  // namespace

BENCHMARK(BM_Backproject)->Unit(benchmark::kMillisecond);
BENCHMARK(BM_Prefilter)->Unit(benchmark::kMillisecond);
// The argument is the thread count: 1 for the one-core figures, 2 for the appliance's two cores.
BENCHMARK(BM_Fuse)->Arg(1)->Arg(2)->Unit(benchmark::kMillisecond);
BENCHMARK(BM_PrefilterPlusFusion)->Arg(1)->Arg(2)->Unit(benchmark::kMillisecond);
BENCHMARK(BM_FramePath)->Arg(1)->Arg(2)->Unit(benchmark::kMillisecond);
BENCHMARK(BM_Reregistration)->Arg(1)->Arg(2)->Unit(benchmark::kMillisecond);
BENCHMARK(BM_Tracking)->Arg(1)->Arg(2)->Unit(benchmark::kMillisecond);
BENCHMARK_MAIN();
