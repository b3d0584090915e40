// depthfuse synth: writes a synthetic scan as a TUM RGB-D folder with its exact ground truth.
#include "cli_util.hpp"
#include "command.hpp"
#include "depthfuse/synthetic/synthetic_sequence.hpp"
#include "depthfuse/synthetic/tum_writer.hpp"

using namespace depthfuse;

namespace {

constexpr const char* kCmd = "synth";
constexpr const char* kUsage =
    "depthfuse synth <corner|room|rooms|furnished|plain> <out-folder> [--frames N] [--seed S]\n"
    "         [--pose-noise-m X] [--pose-noise-deg Y] [--no-noise] [--no-color]\n"
    "  --frames: default 60; furnished and plain (laps of a handheld walk, 560 frames a lap):\n"
    "  1200, two laps and back past the start";

// The scene and its generation as the command line gives them.
Result<synthetic::SyntheticConfig> parse_options(const cli::Args& args) {
  if (args.positional().size() != 2) return invalid_argument("expected a scene and an out-folder");
  synthetic::SyntheticConfig c;
  auto kind = synthetic::parse_scene_kind(args.positional()[0]);
  if (!kind) return kind.status();
  c.scene = *kind;
  long frames = synthetic::default_frames(c.scene), seed = static_cast<long>(c.seed);
  std::string err;
  if (!args.get_int("frames", &frames, &err, daemon::closed(1, INT32_MAX)) ||
      !args.get_int("seed", &seed, &err, daemon::closed(0, INT64_MAX)) ||
      !args.get_double("pose-noise-m", &c.pose_noise_m, &err) ||
      !args.get_double("pose-noise-deg", &c.pose_noise_deg, &err))
    return invalid_argument(err);
  c.frames = static_cast<int>(frames);
  c.seed = static_cast<uint64_t>(seed);
  if (args.has("no-noise")) c.noise.enabled = false;
  return c;
}

int run(int argc, char** argv) {
  daemon::Startup startup(cli::offline_program(kCmd, kUsage,
                                               {"frames", "seed", "pose-noise-m", "pose-noise-deg"},
                                               {"no-noise", "no-color"}, 2, false),
                          argc, argv);
  if (auto code = startup.exit_code()) return *code;
  const cli::Args& args = startup.args();
  const auto c = parse_options(args);
  if (!c) return startup.usage_error(c.status().message());
  auto seq = synthetic::SyntheticSequence::create(*c);
  if (!seq) return cli::fail(seq.status().message());
  const Status s = synthetic::write_tum_folder(*seq, args.positional()[1], !args.has("no-color"));
  if (!s) return cli::fail(s.message());
  std::printf("wrote %d frames of '%s' to %s (pose noise %.3f m, %.2f deg; sensor noise %s)\n", c->frames,
              args.positional()[0].c_str(), args.positional()[1].c_str(), c->pose_noise_m, c->pose_noise_deg,
              c->noise.enabled ? "on" : "off");
  return 0;
}

}  // namespace

DF_REGISTER_COMMAND(synth, kCmd, kUsage, "render a synthetic scan (TUM folder + exact ground truth)", run);
