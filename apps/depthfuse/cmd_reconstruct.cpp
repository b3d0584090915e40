// depthfuse reconstruct: the paper's batch pipeline over a recorded or synthetic sequence.
#include <algorithm>
#include <chrono>
#include <filesystem>
#include <sstream>

#include "cli_util.hpp"
#include "command.hpp"
#include "depthfuse/ply.hpp"
#include "depthfuse/replay/tum_source.hpp"
#include "depthfuse/source_factory.hpp"
#include "depthfuse/trajectory.hpp"

namespace fs = std::filesystem;
using namespace depthfuse;

namespace {

constexpr const char* kCmd = "reconstruct";
constexpr const char* kUsage =
    "depthfuse reconstruct <tum-folder|lcm-log|synthetic:SCENE[?...]> -o cloud.ply\n"
    "         [--poses FILE] [--track] [--method full|ylimaki17|kyostila13] [--iterations N]\n"
    "         [--config FILE] [--camera camera.toml] [--trajectory-out FILE] [--report FILE]\n"
    "         [--max-frames N] [--stride N]";

struct Input {
  std::vector<Frame> frames;
  std::string description;
  std::string pose_origin;  // where the initial poses come from, "" = none
};

Result<Input> load_input(const std::string& input, const cli::Args& args, const AppConfig& config,
                         cli::Progress& progress) {
  Input in;
  long max_frames = 0, stride = 1;
  std::string err;
  if (!args.get_int("max-frames", &max_frames, &err, daemon::closed(0, INT32_MAX)) ||
      !args.get_int("stride", &stride, &err, daemon::closed(1, INT32_MAX)))
    return invalid_argument(err);

  std::unique_ptr<FrameSource> source;
  if (fs::is_directory(input)) {
    replay::TumReplayConfig rc;
    rc.max_frames = static_cast<size_t>(max_frames);
    rc.stride = static_cast<size_t>(stride);
    if (args.has("camera")) {
      auto cam = replay::read_camera_file(args.get("camera"));
      if (!cam) return cam.status();
      rc.intrinsics = cam->intrinsics;
      rc.depth_scale = cam->depth_scale;
    }
    if (args.has("poses")) {
      rc.poses_path = args.get("poses");
      in.pose_origin = rc.poses_path;
    } else if (!args.has("track") && fs::exists(input + "/groundtruth.txt")) {
      rc.use_groundtruth = true;
      in.pose_origin = input + "/groundtruth.txt";
    }
    auto s = replay::TumSource::open(input, rc);
    if (!s) return s.status();
    source = std::move(s.value());
  } else {
    std::string spec = input;
    if (input.find(':') == std::string::npos || fs::exists(input)) spec = "lcmlog:" + input;
    if (!fs::exists(input) && spec.rfind("lcmlog:", 0) == 0)
      return not_found("no such folder or file: " + input);
    auto s = open_frame_source(spec, config);
    if (!s) return s.status();
    source = std::move(s.value());
    if (args.has("poses")) return invalid_argument("--poses works with TUM folders only");
  }
  in.description = source->describe();

  const auto total = source->frame_count();
  for (size_t i = 0;; ++i) {
    auto f = source->next();
    if (f.status().code() == StatusCode::kEndOfStream) break;
    if (!f) return f.status();
    if (stride > 1 && !fs::is_directory(input) && i % stride) continue;
    in.frames.push_back(std::move(f.value()));
    if (total) progress("reading frames", in.frames.size(), *total);
    if (max_frames && in.frames.size() >= static_cast<size_t>(max_frames)) break;
  }
  if (in.frames.empty()) return invalid_argument(input + ": empty sequence, no frames to fuse");

  if (!in.pose_origin.empty()) {
    for (size_t i = 0; i < in.frames.size(); ++i)
      if (!in.frames[i].T_world_cam_hint)
        return not_found("frame " + std::to_string(i) + " (t = " +
                         std::to_string(in.frames[i].utime / 1e6) + " s) has no pose within 20 ms in " +
                         in.pose_origin);
  } else if (!args.has("track")) {
    const bool all = std::all_of(in.frames.begin(), in.frames.end(),
                                 [](const Frame& f) { return f.T_world_cam_hint.has_value(); });
    if (all) in.pose_origin = "the frames' pose hints";
  }
  return in;
}

int run(int argc, char** argv) {
  cli::Args args(argc, argv, {"track", "help"});
  if (args.has("help")) return std::printf("usage: %s\n", kUsage), 0;
  if (!args.ok()) return cli::fail(args.error());
  const std::string bad = args.unknown({"poses", "track", "method", "iterations", "config", "camera",
                                        "trajectory-out", "report", "max-frames", "stride", "output"});
  if (!bad.empty()) return cli::fail("unknown option " + bad + "\nusage: " + kUsage);
  if (args.positional().size() != 1 || !args.has("output"))
    return cli::fail(std::string("expected one input and -o cloud.ply\nusage: ") + kUsage);

  auto config = cli::load_config_or_report(args);
  if (!config) return 1;
  ReconstructionConfig rc = config->reconstruction;
  if (args.has("method") && !parse_method(args.get("method"), &rc.pipeline.method))
    return cli::fail("--method must be full, ylimaki17 or kyostila13, got '" + args.get("method") + "'");
  long iterations = rc.pipeline.outer_iterations;
  std::string err;
  if (!args.get_int("iterations", &iterations, &err, daemon::closed(0, cli::kMaxIterations)))
    return cli::fail(err);
  rc.pipeline.outer_iterations = static_cast<int>(iterations);

  cli::Progress progress;
  const auto t0 = std::chrono::steady_clock::now();
  auto input = load_input(args.positional()[0], args, *config, progress);
  if (!input) return cli::fail(input.status().message());
  std::vector<Frame>& frames = input->frames;

  std::vector<Pose> initial;
  std::string pose_note = input->pose_origin;
  if (pose_note.empty()) {
    auto tracked = track_sequence(frames, rc, progress.fn());
    if (!tracked) return cli::fail(tracked.status().message());
    // A lost frame's pose is unknown: it is left out of the cloud and the trajectory.
    std::vector<Frame> kept;
    for (size_t i = 0; i < frames.size(); ++i) {
      if (tracked->state[i] == TrackingState::kLost) continue;
      kept.push_back(std::move(frames[i]));
      initial.push_back(tracked->T_world_cam[i]);
    }
    frames = std::move(kept);
    pose_note = "tracked from the first frame: " + std::to_string(tracked->uncertain) +
                " frames uncertain, " + std::to_string(tracked->lost) + " lost (left out)";
  } else {
    for (const Frame& f : frames) initial.push_back(*f.T_world_cam_hint);
  }

  auto result = reconstruct_batch(frames, initial, rc, progress.fn());
  if (!result) return cli::fail(result.status().message());
  const double seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();

  const bool has_color = std::any_of(frames.begin(), frames.end(), [](const Frame& f) { return !f.color.empty(); });
  PlyOptions po;
  po.with_color = has_color;
  const PointArrays cloud = result->map->gather();
  const Status w = write_ply(args.get("output"), cloud, po);
  if (!w) return cli::fail(w.message());
  if (args.has("trajectory-out")) {
    std::vector<StampedPose> traj(frames.size());
    for (size_t i = 0; i < frames.size(); ++i) traj[i] = {frames[i].utime / 1e6, result->T_world_cam[i]};
    const Status s = write_tum_trajectory(args.get("trajectory-out"), traj);
    if (!s) return cli::fail(s.message());
  }

  std::ostringstream r;
  r << "depthfuse reconstruct\n"
    << "  input:        " << input->description << "\n"
    << "  frames:       " << frames.size() << "\n"
    << "  initial poses: " << pose_note << "\n"
    << "  method:       " << to_string(rc.pipeline.method) << "\n"
    << "  measurements: " << result->input_measurements << " valid depth pixels\n"
    << "  pre-filter:   " << result->prefiltered << " removed\n"
    << "  post-filter:  " << result->postfiltered << " removed\n"
    << "  points:       " << cloud.size() << " (reduction "
    << 100.0 * (1.0 - static_cast<double>(cloud.size()) / std::max<size_t>(1, result->input_measurements))
    << " %)\n"
    << "  iterations:\n";
  for (const auto& it : result->iterations) r << cli::describe_iteration(it, frames.size());
  if (result->converged_early) r << "  stopped early: the poses stopped moving\n";
  r << "  cloud:        " << args.get("output") << "\n";
  if (args.has("trajectory-out")) r << "  trajectory:   " << args.get("trajectory-out") << "\n";
  r << "  time:         " << seconds << " s\n";
  std::fputs(r.str().c_str(), stdout);
  if (args.has("report")) {
    FILE* f = std::fopen(args.get("report").c_str(), "w");
    if (!f) return cli::fail("cannot write report " + args.get("report"));
    std::fputs(r.str().c_str(), f);
    std::fclose(f);
  }
  return 0;
}

}  // namespace

DF_REGISTER_COMMAND(reconstruct, kCmd, kUsage,
                    "fuse a depth sequence into one point cloud (the paper's pipeline)", run);
