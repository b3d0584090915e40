// Speed and sanity figures of the synthetic source: CPU milliseconds per rendered frame (exact and
// with noise) for each built-in scene, and how the depths of its trajectory fall within the sensor
// range.
//
//   depthfuse_synthetic_bench [frames_per_scene [corner|room|rooms]]   (default 60, all scenes)
//
// Not a test: it prints figures (speed targets are not asserted anywhere).
#include <algorithm>
#include <cstdio>
#include <cstdlib>
#include <ctime>
#include <limits>
#include <string>

#include "depthfuse/base/log.hpp"
#include "depthfuse/synthetic/synthetic_sequence.hpp"

using depthfuse::Frame;
using namespace depthfuse::synthetic;

DF_LOG_CATEGORY(Bench)

namespace {

// CPU time of this thread: the figures stay meaningful on a loaded machine.
double now_ms() {
  timespec ts{};
  clock_gettime(CLOCK_THREAD_CPUTIME_ID, &ts);
  return 1e3 * static_cast<double>(ts.tv_sec) + 1e-6 * static_cast<double>(ts.tv_nsec);
}

}  // namespace

int main(int argc, char** argv) {
  depthfuse::log::set_program_name("depthfuse_synthetic_bench");
  const int frames = argc > 1 ? std::max(1, std::atoi(argv[1])) : 60;
  std::printf("%-6s %8s %10s %10s %9s %9s %9s\n", "scene", "frames", "exact_ms", "noisy_ms",
              "valid_%", "near_%", "far_%");
  for (SceneKind kind : {SceneKind::kCorner, SceneKind::kRoom, SceneKind::kRooms}) {
    if (argc > 2 && std::string(argv[2]) != to_string(kind)) continue;
    SyntheticConfig config;
    config.scene = kind;
    // The rooms walk is time-based: spread the sampled frames over one tour.
    const int step = kind == SceneKind::kRooms ? 72 : 1;
    config.frames = frames * step;
    auto seq = SyntheticSequence::create(config);
    if (!seq.is_ok()) {
      DF_LOG(Bench, Error) << seq.status().to_string();
      return 1;
    }
    // Depth statistics over unlimited rays: how much of the view is nearer/farther than the range.
    SyntheticConfig wide = config;
    wide.min_depth_m = 1e-3;
    wide.max_depth_m = 1e3;
    wide.noise.enabled = false;
    auto wide_seq = SyntheticSequence::create(wide);
    Frame frame;
    double exact_ms = 0.0, noisy_ms = 0.0;
    size_t valid = 0, near = 0, far = 0, total = 0;
    for (int k = 0; k < frames; ++k) {
      const size_t i = static_cast<size_t>(k) * step;
      double t0 = now_ms();
      seq->render_into(i, false, &frame);
      exact_ms += now_ms() - t0;
      t0 = now_ms();
      seq->render_into(i, true, &frame);
      noisy_ms += now_ms() - t0;
      wide_seq->render_into(i, false, &frame, false);
      for (float z : frame.depth.depth_m) {
        ++total;
        if (z <= 0.0f) continue;
        if (z < config.min_depth_m)
          ++near;
        else if (z > config.max_depth_m)
          ++far;
        else
          ++valid;
      }
    }
    std::printf("%-6s %8d %10.2f %10.2f %9.1f %9.2f %9.2f\n", to_string(kind), frames,
                exact_ms / frames, noisy_ms / frames, 100.0 * valid / total, 100.0 * near / total,
                100.0 * far / total);
  }
  return 0;
}
