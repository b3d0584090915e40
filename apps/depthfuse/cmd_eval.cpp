// depthfuse eval: the paper's figures for a reconstructed cloud against the ground truth.
#include <algorithm>
#include <filesystem>
#include <fstream>
#include <optional>
#include <sstream>

#include "cli_util.hpp"
#include "command.hpp"
#include "error_curve.hpp"
#include "depthfuse/evaluation.hpp"
#include "depthfuse/input_file.hpp"
#include "depthfuse/measurement.hpp"
#include "depthfuse/ply.hpp"
#include "depthfuse/replay/tum_source.hpp"
#include "depthfuse/synthetic/scene.hpp"
#include "depthfuse/synthetic/synthetic_sequence.hpp"
#include "depthfuse/trajectory.hpp"

namespace fs = std::filesystem;
using namespace depthfuse;

namespace {

constexpr const char* kCmd = "eval";
constexpr const char* kUsage =
    "depthfuse eval <tum-folder> <cloud.ply> [--trajectory FILE] [--reference CLOUD]\n"
    "         [--out PREFIX] [--label NAME] [--no-align]";

// Noise-free points of every frame at its true pose, 2 mm apart: the observed ground-truth surface.
// Sampled a frame at a time into one set of voxels: downsampling the whole cloud again on every
// frame made the cost grow with the square of the scan's length.
PointArrays synthetic_truth_cloud(const synthetic::SyntheticSequence& seq) {
  VoxelSampler truth(0.002);
  MeasurementImage m;
  SensorModelConfig sensor;
  for (size_t i = 0; i < seq.size(); ++i) {
    Frame f = seq.render(i, false);
    if (!backproject(f, sensor, FusionConfig{}, &m).is_ok()) continue;
    const Pose T = seq.T_world_cam_true(i);
    PointArrays frame_pts;
    for (size_t p = 0; p < m.pixel_count(); p += 1) {
      if (!m.valid[p]) continue;
      PointRecord r;
      r.position_m = (T * Eigen::Vector3d(m.x[p], m.y[p], m.z[p])).cast<float>();
      frame_pts.push_back(r);
    }
    truth.add(frame_pts);
  }
  return truth.take();
}

struct Options {
  std::string folder, cloud, label, prefix;  // prefix: of the report and curve files
  std::optional<std::string> trajectory, reference;
  bool align = true;
};

Result<Options> parse_options(const cli::Args& args) {
  if (args.positional().size() != 2) return invalid_argument("expected a TUM folder and a cloud");
  Options o;
  o.folder = args.positional()[0];
  o.cloud = args.positional()[1];
  const fs::path cloud(o.cloud);
  o.label = args.get("label", cloud.stem().string());
  o.prefix = args.get("out", (cloud.parent_path() / cloud.stem()).string() + ".eval");
  if (args.has("trajectory")) o.trajectory = args.get("trajectory");
  if (args.has("reference")) o.reference = args.get("reference");
  o.align = !args.has("no-align");
  return o;
}

// Valid depth pixels of every frame of the folder, for the reduction ratio.
Result<size_t> count_measurements(const std::string& folder) {
  replay::TumReplayConfig rc;
  rc.load_color = false;
  auto source = replay::TumSource::open(folder, rc);
  if (!source) return source.status();
  size_t measurements = 0;
  for (size_t i = 0; i < *(*source)->frame_count(); ++i) {
    auto f = (*source)->load(i);
    if (!f) return f.status();
    for (float d : f->depth.depth_m) measurements += d > 0;
  }
  return measurements;
}

// The ATE of a trajectory against the folder's ground truth, as a line of the report, and the
// cameras' rigid alignment to the truth (not the ATE's position-only one: see align_cameras()).
struct TrajectoryScore {
  std::string line;
  Pose alignment;
};

Result<TrajectoryScore> score_trajectory(const std::string& folder, const std::string& path) {
  auto est = read_tum_trajectory(path);
  if (!est) return est.status();
  if (!fs::exists(folder + "/groundtruth.txt"))
    return not_found("--trajectory needs " + folder + "/groundtruth.txt for the ATE");
  auto gt = read_tum_trajectory(folder + "/groundtruth.txt");
  if (!gt) return gt.status();
  std::vector<Pose> a, b;
  for (const auto& p : *est) {
    const long j = nearest_pose(*gt, p.timestamp_s, 0.02);
    if (j < 0) continue;
    a.push_back(p.T_world_cam);
    b.push_back((*gt)[j].T_world_cam);
  }
  auto ate = absolute_trajectory_error(a, b);
  if (!ate) return ate.status();
  char line[200];
  std::snprintf(line, sizeof line,
                "  ATE RMSE:          %.2f mm aligned (%.2f mm unaligned, max %.2f mm, %zu poses)\n",
                ate->rmse_m * 1e3, ate->unaligned_rmse_m * 1e3, ate->max_m * 1e3, ate->pairs);
  auto cameras = align_cameras(a, b);
  if (!cameras) return cameras.status();
  return TrajectoryScore{line, *cameras};
}

void transform(const Pose& T, PointArrays* cloud) {
  const Eigen::Matrix3f R = T.linear().cast<float>();
  const Eigen::Vector3f t = T.translation().cast<float>();
  for (size_t i = 0; i < cloud->size(); ++i) cloud->position_m[i] = R * cloud->position_m[i] + t;
}

// The ground truth a cloud is measured against, and the cloud's distances to it.
struct Truth {
  DistanceSummary distances;
  PointArrays cloud;
  std::string name;
};

// A synthetic scan's analytic surfaces (its scene.toml), and the noise-free points of its frames.
Result<Truth> analytic_truth(const std::string& folder, const PointArrays& cloud) {
  auto text = read_input_file(folder + "/scene.toml", "scene file", size_t{16} << 20);
  if (!text) return text.status();
  auto scene = synthetic::Scene::parse_toml(*text, folder + "/scene.toml");
  if (!scene) return scene.status();
  auto gen = synthetic::parse_synthetic_config_toml(*text, folder + "/scene.toml");
  if (!gen) return gen.status();
  std::vector<double> d(cloud.size());
  for (size_t i = 0; i < cloud.size(); ++i) d[i] = scene->distance_m(cloud.position(i).cast<double>());
  auto seq = synthetic::SyntheticSequence::create(*gen);
  if (!seq) return seq.status();
  return Truth{summarize_distances(std::move(d)), synthetic_truth_cloud(*seq),
               "analytic scene (" + folder + "/scene.toml)"};
}

Result<Truth> reference_truth(const std::string& path, const PointArrays& cloud) {
  auto ref = read_ply(path);
  if (!ref) return ref.status();
  DistanceSummary distances = summarize_distances(distances_to_cloud(cloud, *ref, 0.1));
  return Truth{std::move(distances), std::move(*ref), "reference cloud " + path};
}

// The truth's part of the report, and the cumulative error curve as CSV and PNG.
Status describe_truth(const Options& o, const PointArrays& cloud, const Truth& truth,
                      std::ostringstream& r) {
  const DistanceSummary& dist = truth.distances;
  char line[256];
  r << "  ground truth:      " << truth.name << "\n";
  std::snprintf(line, sizeof line,
                "  distance to truth: mean %.2f mm, median %.3f mm, p90 %.2f mm, p95 %.2f mm; %.1f %% within 5 mm\n",
                dist.mean_m * 1e3, dist.median_m * 1e3, dist.p90_m * 1e3, dist.p95_m * 1e3, dist.within_5mm * 100);
  r << line;
  r << "  truth points:      " << truth.cloud.size() << "\n";
  std::snprintf(line, sizeof line, "  compression ratio: %.3f (truth points / cloud points)\n",
                static_cast<double>(truth.cloud.size()) / std::max<size_t>(1, cloud.size()));
  r << line;
  r << "  jaccard index:    ";
  for (double v : {0.005, 0.020, 0.045, 0.085}) {
    std::snprintf(line, sizeof line, " %.0f mm %.3f;", v * 1e3, jaccard_index(cloud, truth.cloud, v));
    r << line;
  }
  r << "\n";
  DF_RETURN_IF_ERROR(cli::write_cumulative_csv(o.prefix + ".errors.csv", dist));
  DF_RETURN_IF_ERROR(cli::write_cumulative_png(o.prefix + ".errors.png", {{o.label, &dist}}));
  r << "  cumulative curve:  " << o.prefix << ".errors.csv, " << o.prefix << ".errors.png\n";
  return Status::ok();
}

// The report: the cloud's size against the input, the ATE, and the distances to the truth when
// there is one (a synthetic scan's analytic scene, or --reference).
Result<std::string> evaluate(const Options& o) {
  auto cloud = read_ply(o.cloud);
  if (!cloud) return cloud.status();
  auto measurements = count_measurements(o.folder);
  if (!measurements) return measurements.status();
  std::ostringstream r;
  r << "depthfuse eval " << o.label << "\n";
  r << "  points:            " << cloud->size() << "\n";
  r << "  input measurements: " << *measurements << "\n";
  r << "  reduction ratio:   " << 100.0 * (1.0 - static_cast<double>(cloud->size()) / std::max<size_t>(1, *measurements)) << " %\n";
  // A reconstruction from perturbed poses is only defined up to a rigid motion (its gauge): the
  // cameras' alignment to the truth places the cloud in the truth's frame.
  if (o.trajectory) {
    auto score = score_trajectory(o.folder, *o.trajectory);
    if (!score) return score.status();
    r << score->line;
    if (o.align) {
      transform(score->alignment, &*cloud);
      r << "  cloud aligned to the truth by the cameras' rigid alignment (--no-align to skip)\n";
    }
  }
  std::optional<Result<Truth>> truth;
  if (fs::exists(o.folder + "/scene.toml") && !o.reference)
    truth = analytic_truth(o.folder, *cloud);
  else if (o.reference)
    truth = reference_truth(*o.reference, *cloud);
  if (truth) {
    if (!*truth) return truth->status();
    DF_RETURN_IF_ERROR(describe_truth(o, *cloud, **truth, r));
  }
  return r.str();
}

int run(int argc, char** argv) {
  daemon::Startup startup(cli::offline_program(kCmd, kUsage, {"trajectory", "reference", "out", "label"},
                                               {"no-align"}, 2, false),
                          argc, argv);
  if (auto code = startup.exit_code()) return *code;
  const auto o = parse_options(startup.args());
  if (!o) return startup.usage_error(o.status().message());
  auto report = evaluate(*o);
  if (!report) return cli::fail(report.status().message());
  std::fputs(report->c_str(), stdout);
  std::ofstream(o->prefix + ".txt") << *report;
  return 0;
}

}  // namespace

DF_REGISTER_COMMAND(eval, kCmd, kUsage, "measure a cloud against ground truth (paper's figures)", run);
