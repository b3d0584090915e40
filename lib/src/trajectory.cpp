#include "depthfuse/trajectory.hpp"

#include <algorithm>
#include <cerrno>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <sstream>

#include <Eigen/Geometry>

#include "depthfuse/input_file.hpp"

namespace depthfuse {

Result<std::vector<StampedPose>> read_tum_trajectory(const std::string& path) {
  // An hour at 30 Hz is about 10 MB of text.
  auto text = read_input_file(path, "trajectory", size_t{256} << 20);
  if (!text) return text.status();
  std::istringstream in(*text);
  std::vector<StampedPose> poses;
  std::string line;
  size_t line_no = 0;
  while (std::getline(in, line)) {
    ++line_no;
    const size_t first = line.find_first_not_of(" \t\r");
    if (first == std::string::npos || line[first] == '#') continue;
    std::istringstream ls(line);
    double v[8];
    std::string tok;
    int k = 0;
    const std::string where = path + ":" + std::to_string(line_no);
    while (ls >> tok) {
      if (k == 8) return invalid_argument(where + ": more than 8 fields (timestamp tx ty tz qx qy qz qw)");
      char* end = nullptr;
      errno = 0;
      v[k] = std::strtod(tok.c_str(), &end);
      if (end == tok.c_str() || *end != '\0' || errno == ERANGE)
        return invalid_argument(where + ": field " + std::to_string(k + 1) + " '" + tok + "' is not a number");
      if (!std::isfinite(v[k]))
        return invalid_argument(where + ": field " + std::to_string(k + 1) + " is " + tok);
      ++k;
    }
    if (k != 8)
      return invalid_argument(where + ": expected 8 fields (timestamp tx ty tz qx qy qz qw), got " +
                              std::to_string(k));
    Eigen::Quaterniond q(v[7], v[4], v[5], v[6]);
    const double qn = q.norm();
    if (std::abs(qn - 1.0) > 1e-3)
      return invalid_argument(where + ": quaternion is not unit (norm " + std::to_string(qn) + ")");
    StampedPose p;
    p.timestamp_s = v[0];
    p.T_world_cam.linear() = q.normalized().toRotationMatrix();
    p.T_world_cam.translation() = Eigen::Vector3d(v[1], v[2], v[3]);
    poses.push_back(p);
  }
  if (poses.empty()) return invalid_argument(path + ": no poses in trajectory file");
  std::stable_sort(poses.begin(), poses.end(),
                   [](const StampedPose& a, const StampedPose& b) { return a.timestamp_s < b.timestamp_s; });
  return poses;
}

Status write_tum_trajectory(const std::string& path, const std::vector<StampedPose>& poses) {
  TumTrajectoryWriter writer;
  DF_RETURN_IF_ERROR(writer.open(path));
  for (const auto& p : poses) writer.add(p);
  return writer.close();
}

TumTrajectoryWriter::~TumTrajectoryWriter() {
  if (file_) std::fclose(file_);
}

Status TumTrajectoryWriter::open(const std::string& path) {
  if (file_) std::fclose(file_);
  path_ = path;
  file_ = std::fopen(path.c_str(), "w");
  if (!file_) return io_error("cannot create " + path + ": " + std::strerror(errno));
  std::fprintf(file_, "# timestamp tx ty tz qx qy qz qw (camera-to-world), written by depthfuse\n");
  return Status::ok();
}

void TumTrajectoryWriter::add(const StampedPose& p) {
  if (!file_) return;
  const Eigen::Quaterniond q(p.T_world_cam.linear());
  const Eigen::Vector3d t = p.T_world_cam.translation();
  std::fprintf(file_, "%.6f %.6f %.6f %.6f %.9f %.9f %.9f %.9f\n", p.timestamp_s, t.x(), t.y(),
               t.z(), q.x(), q.y(), q.z(), q.w());
}

Status TumTrajectoryWriter::close() {
  if (!file_) return io_error("cannot write " + path_ + ": not open");
  const bool ok = std::fflush(file_) == 0 && !std::ferror(file_);
  const bool closed = std::fclose(file_) == 0;
  file_ = nullptr;
  if (!ok || !closed) return io_error("cannot write " + path_ + ": " + std::strerror(errno));
  return Status::ok();
}

long nearest_pose(const std::vector<StampedPose>& poses, double t_s, double max_dt_s) {
  if (poses.empty()) return -1;
  auto it = std::lower_bound(poses.begin(), poses.end(), t_s,
                             [](const StampedPose& p, double t) { return p.timestamp_s < t; });
  long best = -1;
  double best_dt = max_dt_s;
  for (auto c : {it, it == poses.begin() ? it : it - 1}) {
    if (c == poses.end()) continue;
    const double dt = std::abs(c->timestamp_s - t_s);
    if (dt <= best_dt) {
      best_dt = dt;
      best = static_cast<long>(c - poses.begin());
    }
  }
  return best;
}

Result<AteResult> absolute_trajectory_error(const std::vector<Pose>& est, const std::vector<Pose>& truth) {
  if (est.size() != truth.size()) return invalid_argument("trajectories differ in length");
  if (est.size() < 3) return invalid_argument("need at least 3 poses for the ATE");
  const size_t n = est.size();
  Eigen::Matrix3Xd A(3, n), B(3, n);
  for (size_t i = 0; i < n; ++i) {
    A.col(i) = est[i].translation();
    B.col(i) = truth[i].translation();
  }
  const Eigen::Matrix4d T = Eigen::umeyama(A, B, false);
  AteResult r;
  r.pairs = n;
  r.T_truth_estimate.matrix() = T;
  double sq = 0, sq_raw = 0, sum = 0;
  for (size_t i = 0; i < n; ++i) {
    const Eigen::Vector3d a = T.topLeftCorner<3, 3>() * A.col(i) + T.topRightCorner<3, 1>();
    const double e = (a - B.col(i)).norm();
    sq += e * e;
    sum += e;
    r.max_m = std::max(r.max_m, e);
    sq_raw += (A.col(i) - B.col(i)).squaredNorm();
  }
  r.rmse_m = std::sqrt(sq / n);
  r.mean_m = sum / n;
  r.unaligned_rmse_m = std::sqrt(sq_raw / n);
  return r;
}

Result<Pose> align_cameras(const std::vector<Pose>& est, const std::vector<Pose>& truth,
                           double view_m) {
  if (est.size() != truth.size()) return invalid_argument("trajectories differ in length");
  if (est.empty()) return invalid_argument("need at least one pose to align cameras");
  if (!(view_m > 0)) return invalid_argument("the view distance must be > 0");
  const size_t n = est.size();
  Eigen::Matrix3Xd A(3, 4 * n), B(3, 4 * n);
  for (size_t i = 0; i < n; ++i) {
    A.col(4 * i) = est[i].translation();
    B.col(4 * i) = truth[i].translation();
    for (int axis = 0; axis < 3; ++axis) {
      A.col(4 * i + 1 + axis) = est[i].translation() + view_m * est[i].linear().col(axis);
      B.col(4 * i + 1 + axis) = truth[i].translation() + view_m * truth[i].linear().col(axis);
    }
  }
  Pose T;
  T.matrix() = Eigen::umeyama(A, B, false);
  return T;
}

}  // namespace depthfuse
