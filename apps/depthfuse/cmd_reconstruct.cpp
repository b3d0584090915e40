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

// What the command line asks for, checked before anything is read.
struct Options {
  std::string input, output;
  ReconstructionConfig rc;
  bool track = false;
  // Set when given, even as "": an empty path is refused where it is opened.
  std::optional<std::string> poses, camera, trajectory_out, report;
  size_t max_frames = 0;  // 0 = all
  size_t stride = 1;
  std::optional<mesh::MeshOptions> mesh;  // --mesh
  std::string mesh_path;
};

// An option that is missing, malformed or out of range: an invalid_argument naming it.
Result<Options> parse_options(const daemon::Startup& startup) {
  const cli::Args& args = startup.args();
  if (args.positional().size() != 1 || !args.has("output"))
    return invalid_argument("expected one input and -o cloud.ply");
  Options o;
  o.input = args.positional()[0];
  o.output = args.get("output");
  mesh::MeshOptions mesh_options;
  std::string err;
  if (!cli::parse_mesh_options(args, &mesh_options, &err)) return invalid_argument(err);
  if (const std::string stray = cli::mesh_option_without_mesh(args); !stray.empty())
    return invalid_argument("--" + stray + " without --mesh FILE");
  if (args.has("mesh")) {
    o.mesh_path = args.get("mesh");
    DF_RETURN_IF_ERROR(cli::check_mesh_path(o.mesh_path));
    o.mesh = mesh_options;
  }
  o.rc = startup.config().reconstruction;
  if (args.has("method") && !parse_method(args.get("method"), &o.rc.pipeline.method))
    return invalid_argument("--method must be full, ylimaki17 or kyostila13, got '" +
                            args.get("method") + "'");
  long iterations = o.rc.pipeline.outer_iterations, max_frames = 0, stride = 1;
  if (!args.get_int("iterations", &iterations, &err, daemon::closed(0, cli::kMaxIterations)) ||
      !args.get_int("max-frames", &max_frames, &err, daemon::closed(0, INT32_MAX)) ||
      !args.get_int("stride", &stride, &err, daemon::closed(1, INT32_MAX)))
    return invalid_argument(err);
  o.rc.pipeline.outer_iterations = static_cast<int>(iterations);
  o.max_frames = static_cast<size_t>(max_frames);
  o.stride = static_cast<size_t>(stride);
  o.track = args.has("track");
  for (auto [name, value] : {std::pair{"poses", &o.poses}, std::pair{"camera", &o.camera},
                              std::pair{"trajectory-out", &o.trajectory_out},
                              std::pair{"report", &o.report}})
    if (args.has(name)) *value = args.get(name);
  return o;
}

Result<Input> open_input(const Options& o, const AppConfig& config) {
  Input in;
  in.max_frames = o.max_frames;
  if (fs::is_directory(o.input)) {
    replay::TumReplayConfig rc;
    rc.max_frames = o.max_frames;
    rc.stride = o.stride;
    if (o.camera) {
      auto cam = replay::read_camera_file(*o.camera);
      if (!cam) return cam.status();
      rc.intrinsics = cam->intrinsics;
      rc.depth_scale = cam->depth_scale;
      rc.distortion = cam->distortion;
      rc.color_stamp_offset_s = cam->color_stamp_offset_s;
    }
    if (o.poses) {
      rc.poses_path = *o.poses;
      in.pose_origin = rc.poses_path;
    } else if (!o.track && fs::exists(o.input + "/groundtruth.txt")) {
      rc.use_groundtruth = true;
      in.pose_origin = o.input + "/groundtruth.txt";
    }
    auto s = replay::TumSource::open(o.input, rc);
    if (!s) return s.status();
    in.source = std::move(s.value());
  } else {
    std::string spec = o.input;
    if (o.input.find(':') == std::string::npos || fs::exists(o.input)) spec = "lcmlog:" + o.input;
    if (!fs::exists(o.input) && spec.rfind("lcmlog:", 0) == 0)
      return not_found("no such folder or file: " + o.input);
    auto s = open_frame_source(spec, config);
    if (!s) return s.status();
    in.source = std::move(s.value());
    if (o.poses) return invalid_argument("--poses works with TUM folders only");
    in.stride = o.stride;
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

// What a run made, for the outputs and the report.
struct Outcome {
  BatchResult result;
  size_t frames = 0;
  bool has_color = false;
  std::string pose_note;  // where the initial poses came from
};

// The initial poses of held frames: tracked from the first frame (a lost frame is left out of the
// frames, the cloud and the trajectory, its pose being unknown), or the frames' own.
Result<std::vector<Pose>> initial_poses(Input& in, std::vector<Frame>& frames,
                                        const ReconstructionConfig& rc, cli::Progress& progress,
                                        std::string* pose_note) {
  std::vector<Pose> initial;
  if (pose_note->empty()) {
    auto tracked = track_sequence(frames, rc, progress.fn());
    if (!tracked) return tracked.status();
    std::vector<Frame> kept;
    for (size_t i = 0; i < frames.size(); ++i) {
      if (tracked->state[i] == TrackingState::kLost) continue;
      kept.push_back(std::move(frames[i]));
      initial.push_back(tracked->T_world_cam[i]);
    }
    frames = std::move(kept);
    *pose_note = "tracked from the first frame: " + std::to_string(tracked->uncertain) +
                 " frames uncertain, " + std::to_string(tracked->lost) + " lost (left out), " +
                 std::to_string(tracked->relocalised) + " relocalised (" +
                 std::to_string(tracked->ambiguous) + " places refused as ambiguous); " +
                 std::to_string(tracked->keyframes) + " keyframes, " +
                 std::to_string(tracked->loops) + " loop closures (the poses moved " +
                 std::to_string(tracked->corrections) + " times)";
    return initial;
  }
  for (size_t i = 0; i < frames.size(); ++i) {
    if (!frames[i].T_world_cam_hint) {
      in.taken = i + 1;
      return in.missing_pose(frames[i], false);
    }
    initial.push_back(*frames[i].T_world_cam_hint);
  }
  return initial;
}

// The batch pipeline over every frame held in memory: initial poses, then fusion and the
// re-registration rounds.
Result<Outcome> fuse_held(Input& in, const Options& o, bool rounds, bool from_hints,
                          TumTrajectoryWriter* trajectory, cli::Progress& progress) {
  Outcome out;
  out.pose_note = in.pose_origin;
  auto held = hold_frames(in,
                          rounds ? "re-registration (--iterations " +
                                       std::to_string(o.rc.pipeline.outer_iterations) + ")"
                                 : std::string("tracking (--track, or no poses in the input)"),
                          !out.pose_note.empty(), progress);
  if (!held) return held.status().with_context(o.input);
  std::vector<Frame>& frames = *held;
  out.frames = frames.size();
  out.has_color = std::any_of(frames.begin(), frames.end(),
                              [](const Frame& f) { return !f.color.empty(); });
  // Hints on some frames only: tracked, as hints are all or nothing.
  if (from_hints && !std::all_of(frames.begin(), frames.end(), [](const Frame& f) {
        return f.T_world_cam_hint.has_value();
      }))
    out.pose_note.clear();
  const bool given = !out.pose_note.empty();
  auto initial = initial_poses(in, frames, o.rc, progress, &out.pose_note);
  if (!initial) return given ? initial.status().with_context(o.input) : initial.status();
  auto batch = reconstruct_batch(frames, *initial, o.rc, progress.fn());
  if (!batch) return batch.status();
  out.result = std::move(*batch);
  for (size_t i = 0; i < frames.size(); ++i)
    trajectory->add({frames[i].utime / 1e6, out.result.T_world_cam[i]});
  return out;
}

// The whole run: poses from a file (TUM), or else from the frames' own hints when the first has
// one, or tracked; streamed when there are poses and no rounds, else held.
Result<Outcome> reconstruct(Input& in, const Options& o, TumTrajectoryWriter* trajectory,
                            cli::Progress& progress) {
  bool from_hints = false;
  if (in.pose_origin.empty() && !o.track) {
    auto first = in.peek();
    if (!first) return first.status().with_context(o.input);
    from_hints = *first && (*first)->T_world_cam_hint;
    if (from_hints) in.pose_origin = "the frames' pose hints";
  }
  const bool rounds = o.rc.with_method(o.rc.pipeline.method).registration.enabled &&
                      o.rc.pipeline.outer_iterations > 0;
  if (rounds || in.pose_origin.empty())
    return fuse_held(in, o, rounds, from_hints, trajectory, progress);
  Outcome out;
  out.pose_note = in.pose_origin;
  auto fused = fuse_streamed(in, o.rc, from_hints, o.trajectory_out ? trajectory : nullptr,
                             &out.has_color, progress);
  if (!fused) return fused.status().with_context(o.input);
  out.result = std::move(*fused);
  out.frames = in.taken;
  return out;
}

// The cloud, the mesh (its report line in *mesh_line) and the trajectory.
Status write_outputs(const Options& o, const Outcome& out, const PointArrays& cloud,
                     TumTrajectoryWriter* trajectory, std::string* mesh_line) {
  PlyOptions po;
  po.with_color = out.has_color;
  DF_RETURN_IF_ERROR(write_ply(o.output, cloud, po));
  if (o.mesh) {
    const auto m0 = std::chrono::steady_clock::now();
    mesh::MeshOptions options = *o.mesh;
    options.with_color = out.has_color;
    mesh::MeshReport mesh_report;
    auto m = mesh::mesh_points(cloud, options, &mesh_report);
    if (!m) return m.status();
    auto line = cli::write_mesh(
        o.mesh_path, *m, mesh_report,
        std::chrono::duration<double>(std::chrono::steady_clock::now() - m0).count());
    if (!line) return line.status();
    *mesh_line = *line;
  }
  if (o.trajectory_out) DF_RETURN_IF_ERROR(trajectory->close());
  return Status::ok();
}

std::string describe(const Options& o, const Input& in, const Outcome& out, size_t points,
                     const std::string& mesh_line, double seconds) {
  const BatchResult& result = out.result;
  std::ostringstream r;
  r << "depthfuse reconstruct\n"
    << "  input:        " << in.description << "\n"
    << "  frames:       " << out.frames << "\n"
    << "  initial poses: " << out.pose_note << "\n"
    << "  method:       " << to_string(o.rc.pipeline.method) << "\n"
    << "  measurements: " << result.input_measurements << " valid depth pixels\n"
    << "  pre-filter:   " << result.prefiltered << " removed\n"
    << "  post-filter:  " << result.postfiltered << " removed\n"
    << "  points:       " << points << " (reduction "
    << 100.0 * (1.0 - static_cast<double>(points) / std::max<size_t>(1, result.input_measurements))
    << " %)\n"
    << "  iterations:\n";
  for (const auto& it : result.iterations) r << cli::describe_iteration(it, out.frames);
  if (result.converged_early) r << "  stopped early: the poses stopped moving\n";
  r << "  cloud:        " << o.output << "\n";
  if (!mesh_line.empty()) r << "  " << mesh_line;
  if (o.trajectory_out) r << "  trajectory:   " << *o.trajectory_out << "\n";
  r << "  time:         " << seconds << " s\n";
  return r.str();
}

int run(int argc, char** argv) {
  std::vector<std::string> options = {"poses", "method", "iterations", "camera", "trajectory-out",
                                      "report", "max-frames", "stride", "output", "mesh"};
  options.insert(options.end(), cli::mesh_option_names().begin(), cli::mesh_option_names().end());
  daemon::Startup startup(cli::offline_program(kCmd, kUsage, options, {"track"}, 1, true), argc,
                          argv);
  if (auto code = startup.exit_code()) return *code;
  const auto o = parse_options(startup);
  if (!o) return startup.usage_error(o.status().message());

  cli::Progress progress;
  const auto t0 = std::chrono::steady_clock::now();
  auto input = open_input(*o, startup.config());
  if (!input) return cli::fail(input.status().message());
  TumTrajectoryWriter trajectory;
  if (o->trajectory_out) {
    const Status s = trajectory.open(*o->trajectory_out);
    if (!s) return cli::fail(s.message());
  }
  auto out = reconstruct(*input, *o, &trajectory, progress);
  if (!out) return cli::fail(out.status().message());
  const double seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();

  const PointArrays cloud = out->result.map->gather();
  std::string mesh_line;
  if (const Status w = write_outputs(*o, *out, cloud, &trajectory, &mesh_line); !w)
    return cli::fail(w.message());
  const std::string report = describe(*o, *input, *out, cloud.size(), mesh_line, seconds);
  std::fputs(report.c_str(), stdout);
  if (o->report) {
    FILE* f = std::fopen(o->report->c_str(), "w");
    if (!f) return cli::fail("cannot write report " + *o->report);
    std::fputs(report.c_str(), f);
    std::fclose(f);
  }
  return 0;
}

}  // namespace

DF_REGISTER_COMMAND(reconstruct, kCmd, kUsage,
                    "fuse a depth sequence into one point cloud (the paper's pipeline)", run);
