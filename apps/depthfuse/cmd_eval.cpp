// depthfuse eval: the paper's figures for a reconstructed cloud against the ground truth.
#include <algorithm>
#include <filesystem>
#include <fstream>
#include <sstream>

#include "cli_util.hpp"
#include "command.hpp"
#include "error_curve.hpp"
#include "depthfuse/evaluation.hpp"
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

int run(int argc, char** argv) {
  cli::Args args(argc, argv, {"help", "no-align"});
  if (args.has("help")) return std::printf("usage: %s\n", kUsage), 0;
  if (!args.ok()) return cli::fail(args.error());
  const std::string bad = args.unknown({"trajectory", "reference", "out", "label", "no-align"});
  if (!bad.empty()) return cli::fail("unknown option " + bad + "\nusage: " + kUsage);
  if (args.positional().size() != 2) return cli::fail(std::string("usage: ") + kUsage);
  const std::string folder = args.positional()[0], cloud_path = args.positional()[1];
  const std::string label = args.get("label", fs::path(cloud_path).stem().string());
  std::string prefix = args.get("out", (fs::path(cloud_path).parent_path() / fs::path(cloud_path).stem()).string() + ".eval");

  auto cloud = read_ply(cloud_path);
  if (!cloud) return cli::fail(cloud.status().message());
  replay::TumReplayConfig rc;
  rc.load_color = false;
  auto source = replay::TumSource::open(folder, rc);
  if (!source) return cli::fail(source.status().message());

  // Input measurements, for the reduction ratio.
  size_t measurements = 0;
  for (size_t i = 0; i < *(*source)->frame_count(); ++i) {
    auto f = (*source)->load(i);
    if (!f) return cli::fail(f.status().message());
    for (float d : f->depth.depth_m) measurements += d > 0;
  }

  std::ostringstream r;
  r << "depthfuse eval " << label << "\n";
  r << "  points:            " << cloud->size() << "\n";
  r << "  input measurements: " << measurements << "\n";
  r << "  reduction ratio:   " << 100.0 * (1.0 - static_cast<double>(cloud->size()) / std::max<size_t>(1, measurements)) << " %\n";

  // A reconstruction from perturbed poses is only defined up to a rigid motion (its gauge): the
  // cameras' alignment to the truth places the cloud in the truth's frame. (Not the ATE's
  // position-only alignment: see align_cameras().)
  std::optional<Pose> alignment;
  if (args.has("trajectory")) {
    auto est = read_tum_trajectory(args.get("trajectory"));
    if (!est) return cli::fail(est.status().message());
    if (!fs::exists(folder + "/groundtruth.txt"))
      return cli::fail("--trajectory needs " + folder + "/groundtruth.txt for the ATE");
    auto gt = read_tum_trajectory(folder + "/groundtruth.txt");
    if (!gt) return cli::fail(gt.status().message());
    std::vector<Pose> a, b;
    for (const auto& p : *est) {
      const long j = nearest_pose(*gt, p.timestamp_s, 0.02);
      if (j < 0) continue;
      a.push_back(p.T_world_cam);
      b.push_back((*gt)[j].T_world_cam);
    }
    auto ate = absolute_trajectory_error(a, b);
    if (!ate) return cli::fail(ate.status().message());
    char line[200];
    std::snprintf(line, sizeof line, "  ATE RMSE:          %.2f mm aligned (%.2f mm unaligned, max %.2f mm, %zu poses)\n",
                  ate->rmse_m * 1e3, ate->unaligned_rmse_m * 1e3, ate->max_m * 1e3, ate->pairs);
    r << line;
    auto cameras = align_cameras(a, b);
    if (!cameras) return cli::fail(cameras.status().message());
    alignment = *cameras;
  }
  if (alignment && !args.has("no-align")) {
    const Eigen::Matrix3f R = alignment->linear().cast<float>();
    const Eigen::Vector3f t = alignment->translation().cast<float>();
    for (size_t i = 0; i < cloud->size(); ++i) {
      cloud->position_m[i] = R * cloud->position_m[i] + t;
    }
    r << "  cloud aligned to the truth by the cameras' rigid alignment (--no-align to skip)\n";
  }
  // Ground truth: the synthetic scene's analytic surfaces, or a reference cloud.
  std::optional<DistanceSummary> dist;
  std::optional<PointArrays> truth;
  std::string truth_name;
  if (fs::exists(folder + "/scene.toml") && !args.has("reference")) {
    std::ifstream in(folder + "/scene.toml");
    std::stringstream text;
    text << in.rdbuf();
    auto scene = synthetic::Scene::parse_toml(text.str(), folder + "/scene.toml");
    if (!scene) return cli::fail(scene.status().message());
    auto gen = synthetic::parse_synthetic_config_toml(text.str(), folder + "/scene.toml");
    if (!gen) return cli::fail(gen.status().message());
    std::vector<double> d(cloud->size());
    for (size_t i = 0; i < cloud->size(); ++i) d[i] = scene->distance_m(cloud->position(i).cast<double>());
    dist = summarize_distances(std::move(d));
    auto seq = synthetic::SyntheticSequence::create(*gen);
    if (!seq) return cli::fail(seq.status().message());
    truth = synthetic_truth_cloud(*seq);
    truth_name = "analytic scene (" + folder + "/scene.toml)";
  } else if (args.has("reference")) {
    auto ref = read_ply(args.get("reference"));
    if (!ref) return cli::fail(ref.status().message());
    dist = summarize_distances(distances_to_cloud(*cloud, *ref, 0.1));
    truth = std::move(*ref);
    truth_name = "reference cloud " + args.get("reference");
  }
  if (dist) {
    char line[256];
    r << "  ground truth:      " << truth_name << "\n";
    std::snprintf(line, sizeof line,
                  "  distance to truth: mean %.2f mm, median %.3f mm, p90 %.2f mm, p95 %.2f mm; %.1f %% within 5 mm\n",
                  dist->mean_m * 1e3, dist->median_m * 1e3, dist->p90_m * 1e3, dist->p95_m * 1e3, dist->within_5mm * 100);
    r << line;
    r << "  truth points:      " << truth->size() << "\n";
    std::snprintf(line, sizeof line, "  compression ratio: %.3f (truth points / cloud points)\n",
                  static_cast<double>(truth->size()) / std::max<size_t>(1, cloud->size()));
    r << line;
    r << "  jaccard index:    ";
    for (double v : {0.005, 0.020, 0.045, 0.085}) {
      std::snprintf(line, sizeof line, " %.0f mm %.3f;", v * 1e3, jaccard_index(*cloud, *truth, v));
      r << line;
    }
    r << "\n";
    const Status c = cli::write_cumulative_csv(prefix + ".errors.csv", *dist);
    if (!c) return cli::fail(c.message());
    const Status p = cli::write_cumulative_png(prefix + ".errors.png", {{label, &*dist}});
    if (!p) return cli::fail(p.message());
    r << "  cumulative curve:  " << prefix << ".errors.csv, " << prefix << ".errors.png\n";
  }

  std::fputs(r.str().c_str(), stdout);
  std::ofstream(prefix + ".txt") << r.str();
  return 0;
}

}  // namespace

DF_REGISTER_COMMAND(eval, kCmd, kUsage, "measure a cloud against ground truth (paper's figures)", run);
