// depthfuse reconstruct: the paper's batch pipeline over a recorded or synthetic sequence.
#include <algorithm>
#include <chrono>
#include <filesystem>
#include <optional>
#include <sstream>

#include "cli_util.hpp"
#include "command.hpp"
#include "depthfuse/mesh/surface_mesh.hpp"
#include "depthfuse/ply.hpp"
#include "depthfuse/replay/tum_source.hpp"
#include "depthfuse/source_factory.hpp"
#include "depthfuse/trajectory.hpp"
#include "mesh_options.hpp"

namespace fs = std::filesystem;
using namespace depthfuse;

namespace {

constexpr const char* kCmd = "reconstruct";
constexpr const char* kUsage =
    "depthfuse reconstruct <tum-folder|lcm-log|synthetic:SCENE[?...]> -o cloud.ply\n"
    "         [--poses FILE] [--track] [--method full|ylimaki17|kyostila13] [--iterations N]\n"
    "         [--config FILE] [--camera camera.toml] [--trajectory-out FILE] [--report FILE]\n"
    "         [--max-frames N] [--stride N] [--mesh mesh.ply [--mesh-depth N] [--mesh-trim F]\n"
    "         [--mesh-memory-mb N]]";

// The input sequence as the run reads it. --stride and --max-frames are applied here to sources that
// do not apply them themselves (TUM folders do).
struct Input {
  std::unique_ptr<FrameSource> source;
  std::string description;
  std::string pose_origin;  // where the initial poses come from, "" = none
  size_t stride = 1;
  size_t max_frames = 0;    // 0 = all
  size_t taken = 0;         // frames next() has returned

  // How many frames the run takes, when the source knows its length.
  std::optional<size_t> expected() const {
    const auto total = source->frame_count();
    if (!total) return std::nullopt;
    const size_t n = (*total + stride - 1) / stride;
    return max_frames ? std::min(n, max_frames) : n;
  }

  // The next frame the run takes, nullopt at the end.
  Result<std::optional<Frame>> next() {
    if (peeked_) {
      std::optional<Frame> f = std::move(peeked_);
      peeked_.reset();
      return f;
    }
    if (max_frames && taken >= max_frames) return std::optional<Frame>();
    for (;;) {
      auto f = source->next();
      if (f.status().code() == StatusCode::kEndOfStream) return std::optional<Frame>();
      if (!f) return f.status();
      if (delivered_++ % stride) continue;
      ++taken;
      return std::optional<Frame>(std::move(f.value()));
    }
  }

  // The frame next() returns next, left for it; nullptr at the end.
  Result<const Frame*> peek() {
    if (!peeked_) {
      auto f = next();
      if (!f) return f.status();
      peeked_ = std::move(*f);
    }
    return peeked_ ? &*peeked_ : nullptr;
  }

  // A frame the run needs a pose for and that has none.
  Status missing_pose(const Frame& f, bool from_hints) const {
    return not_found("frame " + std::to_string(taken - 1) + " (t = " + std::to_string(f.utime / 1e6) +
                     " s) has no pose" +
                     (from_hints ? std::string(" hint, as the frames before it had (--track tracks "
                                               "every frame instead)")
                                 : " within 20 ms in " + pose_origin));
  }

 private:
  size_t delivered_ = 0;  // frames the source returned
  std::optional<Frame> peeked_;
};

Result<Input> open_input(const std::string& input, const cli::Args& args, const AppConfig& config) {
  Input in;
  long max_frames = 0, stride = 1;
  std::string err;
  if (!args.get_int("max-frames", &max_frames, &err, daemon::closed(0, INT32_MAX)) ||
      !args.get_int("stride", &stride, &err, daemon::closed(1, INT32_MAX)))
    return invalid_argument(err);
  in.max_frames = static_cast<size_t>(max_frames);

  if (fs::is_directory(input)) {
    replay::TumReplayConfig rc;
    rc.max_frames = static_cast<size_t>(max_frames);
    rc.stride = static_cast<size_t>(stride);
    if (args.has("camera")) {
      auto cam = replay::read_camera_file(args.get("camera"));
      if (!cam) return cam.status();
      rc.intrinsics = cam->intrinsics;
      rc.depth_scale = cam->depth_scale;
      rc.distortion = cam->distortion;
      rc.color_stamp_offset_s = cam->color_stamp_offset_s;
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
    in.source = std::move(s.value());
  } else {
    std::string spec = input;
    if (input.find(':') == std::string::npos || fs::exists(input)) spec = "lcmlog:" + input;
    if (!fs::exists(input) && spec.rfind("lcmlog:", 0) == 0)
      return not_found("no such folder or file: " + input);
    auto s = open_frame_source(spec, config);
    if (!s) return s.status();
    in.source = std::move(s.value());
    if (args.has("poses")) return invalid_argument("--poses works with TUM folders only");
    in.stride = static_cast<size_t>(stride);
  }
  in.description = in.source->describe();
  return in;
}

// Every frame of the input, for the passes of the batch pipeline (re-registration rounds, tracking)
// that go over all of them. Refused before reading past the first frame when they would not fit in
// the memory available, with the figure and how to lower it; a source of unknown length is checked
// as it grows, every kCheckEvery frames for the next kCheckEvery. `why` names the pass that needs
// them; `may_stream` says whether --iterations 0 would not.
Result<std::vector<Frame>> hold_frames(Input& in, const std::string& why, bool may_stream,
                                       cli::Progress& progress) {
  const std::string lower = std::string("take fewer with --max-frames or --stride") +
                            (may_stream ? ", or fuse them as they stream with --iterations 0" : "");
  std::vector<Frame> frames;
  const auto expected = in.expected();
  for (;;) {
    auto f = in.next();
    if (!f) return f.status();
    if (!*f) break;
    constexpr size_t kCheckEvery = 1000;
    if (expected ? frames.empty() : frames.size() % kCheckEvery == 0)
      DF_RETURN_IF_ERROR(cli::check_frames_fit(expected.value_or(kCheckEvery),
                                               cli::frame_bytes(**f), why, lower));
    frames.push_back(std::move(**f));
    if (expected) progress("reading frames", frames.size(), *expected);
  }
  if (frames.empty()) return invalid_argument("empty sequence, no frames to fuse");
  return frames;
}

// The batch pipeline without re-registration rounds, frame by frame as the input delivers them,
// each with the pose it carries: nothing is held per frame (the trajectory goes to its file as it
// grows).
Result<BatchResult> fuse_streamed(Input& in, const ReconstructionConfig& rc, bool from_hints,
                                  TumTrajectoryWriter* trajectory, bool* has_color,
                                  cli::Progress& progress) {
  SequenceFuser fuser(rc);
  const auto expected = in.expected();
  for (;;) {
    auto f = in.next();
    if (!f) return f.status();
    if (!*f) break;
    const Frame& frame = **f;
    if (!frame.T_world_cam_hint) return in.missing_pose(frame, from_hints);
    DF_RETURN_IF_ERROR(fuser.add(frame, *frame.T_world_cam_hint)
                           .with_context("frame " + std::to_string(in.taken - 1)));
    if (trajectory) trajectory->add({frame.utime / 1e6, *frame.T_world_cam_hint});
    *has_color = *has_color || !frame.color.empty();
    if (expected) progress("fusion 0", fuser.frames(), *expected);
  }
  if (fuser.frames() == 0) return invalid_argument("empty sequence, no frames to fuse");
  return fuser.finish();
}
int run(int argc, char** argv) {
  cli::Args args(argc, argv, {"track", "help"});
  if (args.has("help")) return std::printf("usage: %s\n", kUsage), 0;
  if (!args.ok()) return cli::fail(args.error());
  std::vector<std::string> known = {"poses", "track", "method", "iterations", "config", "camera",
                                    "trajectory-out", "report", "max-frames", "stride", "output", "mesh"};
  known.insert(known.end(), cli::mesh_option_names().begin(), cli::mesh_option_names().end());
  const std::string bad = args.unknown(known);
  if (!bad.empty()) return cli::fail("unknown option " + bad + "\nusage: " + kUsage);
  if (args.positional().size() != 1 || !args.has("output"))
    return cli::fail(std::string("expected one input and -o cloud.ply\nusage: ") + kUsage);

  mesh::MeshOptions mesh_options;
  std::string mesh_err;
  if (!cli::parse_mesh_options(args, &mesh_options, &mesh_err)) return cli::fail(mesh_err);
  for (const std::string& name : cli::mesh_option_names())
    if (args.has(name) && !args.has("mesh")) return cli::fail("--" + name + " without --mesh FILE");
  if (args.has("mesh")) {
    const Status path_ok = cli::check_mesh_path(args.get("mesh"));
    if (!path_ok) return cli::fail(path_ok.message());
  }

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
  const std::string& input_name = args.positional()[0];
  auto input = open_input(input_name, args, *config);
  if (!input) return cli::fail(input.status().message());
  auto failed = [&](const Status& st) { return cli::fail(input_name + ": " + st.message()); };

  // Poses come from a file (TUM), or else from the frames' own hints when the first has one.
  bool from_hints = false;
  if (input->pose_origin.empty() && !args.has("track")) {
    auto first = input->peek();
    if (!first) return failed(first.status());
    from_hints = *first && (*first)->T_world_cam_hint;
    if (from_hints) input->pose_origin = "the frames' pose hints";
  }
  const bool rounds = rc.with_method(rc.pipeline.method).registration.enabled &&
                      rc.pipeline.outer_iterations > 0;
  TumTrajectoryWriter trajectory;
  if (args.has("trajectory-out")) {
    const Status s = trajectory.open(args.get("trajectory-out"));
    if (!s) return cli::fail(s.message());
  }

  std::optional<BatchResult> result;
  size_t frame_count = 0;
  bool has_color = false;
  std::string pose_note = input->pose_origin;
  if (!rounds && !pose_note.empty()) {
    auto fused = fuse_streamed(*input, rc, from_hints,
                               args.has("trajectory-out") ? &trajectory : nullptr, &has_color,
                               progress);
    if (!fused) return failed(fused.status());
    result = std::move(*fused);
    frame_count = input->taken;
  } else {
    auto held = hold_frames(*input,
                            rounds ? "re-registration (--iterations " +
                                         std::to_string(rc.pipeline.outer_iterations) + ")"
                                   : std::string("tracking (--track, or no poses in the input)"),
                            !pose_note.empty(), progress);
    if (!held) return failed(held.status());
    std::vector<Frame>& frames = *held;
    frame_count = frames.size();
    has_color = std::any_of(frames.begin(), frames.end(),
                            [](const Frame& f) { return !f.color.empty(); });
    std::vector<Pose> initial;
    // Hints on some frames only: tracked, as hints are all or nothing.
    if (from_hints && !std::all_of(frames.begin(), frames.end(), [](const Frame& f) {
          return f.T_world_cam_hint.has_value();
        }))
      pose_note.clear();
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
                  " frames uncertain, " + std::to_string(tracked->lost) + " lost (left out), " +
                  std::to_string(tracked->relocalised) + " relocalised";
    } else {
      for (size_t i = 0; i < frames.size(); ++i) {
        if (!frames[i].T_world_cam_hint) {
          input->taken = i + 1;
          return failed(input->missing_pose(frames[i], false));
        }
        initial.push_back(*frames[i].T_world_cam_hint);
      }
    }
    auto batch = reconstruct_batch(frames, initial, rc, progress.fn());
    if (!batch) return cli::fail(batch.status().message());
    result = std::move(*batch);
    for (size_t i = 0; i < frames.size(); ++i)
      trajectory.add({frames[i].utime / 1e6, result->T_world_cam[i]});
  }
  const double seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();

  PlyOptions po;
  po.with_color = has_color;
  const PointArrays cloud = result->map->gather();
  const Status w = write_ply(args.get("output"), cloud, po);
  if (!w) return cli::fail(w.message());
  std::string mesh_line;
  if (args.has("mesh")) {
    const auto m0 = std::chrono::steady_clock::now();
    mesh_options.with_color = has_color;
    mesh::MeshReport mesh_report;
    auto m = mesh::mesh_points(cloud, mesh_options, &mesh_report);
    if (!m) return cli::fail(m.status().message());
    auto line = cli::write_mesh(args.get("mesh"), *m, mesh_report,
                                std::chrono::duration<double>(std::chrono::steady_clock::now() - m0).count());
    if (!line) return cli::fail(line.status().message());
    mesh_line = *line;
  }
  if (args.has("trajectory-out")) {
    const Status s = trajectory.close();
    if (!s) return cli::fail(s.message());
  }

  std::ostringstream r;
  r << "depthfuse reconstruct\n"
    << "  input:        " << input->description << "\n"
    << "  frames:       " << frame_count << "\n"
    << "  initial poses: " << pose_note << "\n"
    << "  method:       " << to_string(rc.pipeline.method) << "\n"
    << "  measurements: " << result->input_measurements << " valid depth pixels\n"
    << "  pre-filter:   " << result->prefiltered << " removed\n"
    << "  post-filter:  " << result->postfiltered << " removed\n"
    << "  points:       " << cloud.size() << " (reduction "
    << 100.0 * (1.0 - static_cast<double>(cloud.size()) / std::max<size_t>(1, result->input_measurements))
    << " %)\n"
    << "  iterations:\n";
  for (const auto& it : result->iterations) r << cli::describe_iteration(it, frame_count);
  if (result->converged_early) r << "  stopped early: the poses stopped moving\n";
  r << "  cloud:        " << args.get("output") << "\n";
  if (!mesh_line.empty()) r << "  " << mesh_line;
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
