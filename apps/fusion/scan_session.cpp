#include "scan_session.hpp"

#include <algorithm>
#include <cctype>
#include <ctime>
#include <filesystem>

#include "depthfuse/base/clock.hpp"
#include "depthfuse/base/log.hpp"
#include "depthfuse/trajectory.hpp"

DF_LOG_CATEGORY(Fusion)

namespace depthfuse::fusiond {

namespace {

using Clock = std::chrono::steady_clock;

std::string generated_scan_name() {
  const std::time_t t = std::time(nullptr);
  std::tm tm{};
  localtime_r(&t, &tm);
  char buf[64];
  std::strftime(buf, sizeof(buf), "scan-%Y%m%d-%H%M%S", &tm);
  return buf;
}

// A scan name becomes a file name: keep it to [A-Za-z0-9._-], no leading dot.
bool valid_scan_name(const std::string& s) {
  if (s.empty() || s.size() > 100 || s[0] == '.') return false;
  for (const char c : s)
    if (!(std::isalnum(static_cast<unsigned char>(c)) || c == '.' || c == '_' || c == '-'))
      return false;
  return true;
}

// Writes `path` through a temporary file and a rename, so that a crash or a full disk never leaves
// a truncated file under the final name.
template <typename WriteFn>
Status write_atomically(const std::string& path, WriteFn write) {
  const std::string tmp = path + ".partial";
  Status st = write(tmp);
  std::error_code ec;
  if (st.is_ok()) {
    std::filesystem::rename(tmp, path, ec);
    if (ec) st = io_error("cannot rename " + tmp + " to " + path + ": " + ec.message());
  }
  if (!st.is_ok()) std::filesystem::remove(tmp, ec);
  return st;
}

}  // namespace

ScanSession::ScanSession(const AppConfig& config, CheckpointSink& sink)
    : config_(config), sink_(sink) {}

ScanSession::~ScanSession() = default;

Status ScanSession::may_start() const {
  const auto& f = config_.fusion;
  if (last_start_) {
    const double since_s = std::chrono::duration<double>(Clock::now() - *last_start_).count();
    if (since_s < f.min_scan_interval_s)
      return unavailable("a scan started " + std::to_string(since_s) +
                         " s ago; scans start at most every " +
                         std::to_string(f.min_scan_interval_s) +
                         " s (fusion_daemon.min_scan_interval_s)");
  }
  std::error_code ec;
  std::filesystem::path where = f.scan_dir;
  while (!where.empty() && !std::filesystem::exists(where, ec)) where = where.parent_path();
  const auto space = std::filesystem::space(where.empty() ? "." : where, ec);
  if (ec) return io_error("cannot tell the free space of '" + f.scan_dir + "': " + ec.message());
  const double free_mib = static_cast<double>(space.available) / (1024.0 * 1024.0);
  if (free_mib < f.min_free_disk_mib)
    return unavailable("only " + std::to_string(static_cast<int64_t>(free_mib)) + " MiB free in '" +
                       f.scan_dir + "', below fusion_daemon.min_free_disk_mib (" +
                       std::to_string(static_cast<int64_t>(f.min_free_disk_mib)) + ")");
  return Status::ok();
}

Result<std::string> ScanSession::start(const std::string& requested_name) {
  if (active()) return invalid_argument("scan " + scan_.scan_id + " is running");
  std::string name = requested_name.empty() || requested_name == "-" ? generated_scan_name()
                                                                     : requested_name;
  if (!valid_scan_name(name))
    return invalid_argument("scan name '" + name + "' must be 1-100 characters of A-Z a-z 0-9 . _ -");
  DF_RETURN_IF_ERROR(may_start());
  last_start_ = Clock::now();
  std::error_code ec;
  std::filesystem::create_directories(config_.fusion.scan_dir, ec);
  if (ec)
    return io_error("cannot create the scan directory '" + config_.fusion.scan_dir + "': " +
                    ec.message() + " (set fusion_daemon.scan_dir in the config)");
  scan_ = ScanContext{name, config_.fusion.scan_dir, now_utime(), &config_};
  DF_RETURN_IF_ERROR(sink_.begin_scan(scan_).with_context("checkpoint store"));
  auto reconstructor = std::make_unique<IncrementalReconstructor>(config_.reconstruction);
  RestoredScan restored;
  // An existing scan file (a restart after a crash): continue from its last checkpoint.
  DF_RETURN_IF_ERROR(
      sink_.restore(*reconstructor, &scan_, &restored).with_context("checkpoint store"));
  // A resumed scan takes the id stored in its file, which names the files written at its end (PLY,
  // trajectory): one that is not a scan name ("../../x", "/etc/x") would write them outside
  // scan_dir.
  if (!valid_scan_name(scan_.scan_id))
    return corrupt("the scan file for '" + name + "' holds the scan id '" + scan_.scan_id +
                   "', which is not a scan name: not resumed");
  // Loop closure on a thread of its own: the fusion thread never waits for the optimiser.
  auto path = std::make_unique<FramePath>(*reconstructor, &sink_, /*background_loop_closure=*/true);
  // The graph of before the restart: a later closure moves the poses and the map fused before it.
  if (restored.graph)
    DF_RETURN_IF_ERROR(
        path->restore(std::move(*restored.graph)).with_context("resuming scan " + scan_.scan_id));
  reconstructor_ = std::move(reconstructor);
  path_ = std::move(path);
  trajectory_ = std::move(restored.trajectory);
  trajectory_frames_ = std::move(restored.trajectory_frames);
  // The sequences of frames fused before a resume are not stored.
  trajectory_sequences_.assign(trajectory_.size(), 0);
  last_checkpoint_ = Clock::now();
  const uint32_t next = reconstructor_->next_frame_id();
  const std::string message = "scan " + scan_.scan_id +
                              (next > 1 ? " resumed at frame " + std::to_string(next)
                                        : std::string(" started"));
  DF_LOG(Fusion, Info) << message;
  return message;
}

Result<FrameOutcome> ScanSession::process(const Frame& frame, FrameWork work) {
  if (!active()) return invalid_argument("no scan is running");
  const uint32_t frame_id = reconstructor_->next_frame_id();
  Result<FrameOutcome> outcome = path_->run(frame, work);
  if (!outcome) return outcome;
  if (outcome->correction) {
    correct_trajectory(*outcome->correction, frame_id);
    // The frame log holds poses, not corrections: a crash before the next checkpoint would replay
    // the frames fused since in the corrected frame over a map of the version before: they are not
    // logged (ScanRecorder::record_frame) until a checkpoint takes the correction, which is due
    // at once (checkpoint_due()).
    last_checkpoint_ = Clock::time_point{};
  }
  if (outcome->report.fused()) {
    trajectory_.push_back({frame.utime * 1e-6, outcome->report.T_world_cam});
    trajectory_frames_.push_back(outcome->report.frame_id);
    trajectory_sequences_.push_back(frame.sequence);
  }
  return outcome;
}

int64_t ScanSession::sequence_of(uint32_t frame_id) const {
  const auto it = std::lower_bound(trajectory_frames_.begin(), trajectory_frames_.end(), frame_id);
  if (it == trajectory_frames_.end() || *it != frame_id) return 0;
  return trajectory_sequences_[static_cast<size_t>(it - trajectory_frames_.begin())];
}

bool ScanSession::checkpoint_due() const {
  if (!active() || !sink_.durable() || sink_.checkpoint_in_flight()) return false;
  // After a correction (process() made last_checkpoint_ long ago) one is due at once. It stores
  // the chunks the deformation's sweep has not brought up to date as they are, with the points
  // waiting for them: nothing is brought up to date for it.
  return Clock::now() - last_checkpoint_ >
         std::chrono::duration<double>(config_.fusion.checkpoint_interval_s -
                                       sink_.checkpoint_latency_s());
}

Status ScanSession::checkpoint(const std::string& reason, const FusionProgress& progress) {
  if (!active()) return invalid_argument("no scan is running");
  last_checkpoint_ = Clock::now();
  sink_.keep_graph(path_->checkpoint_state());
  return sink_.checkpoint(reason, *reconstructor_, progress);
}

void ScanSession::correct_trajectory(const AppliedCorrection& correction, uint32_t before_frame) {
  for (size_t i = 0; i < trajectory_.size(); ++i)
    trajectory_[i].T_world_cam =
        correction.motion_of(trajectory_frames_[i]) * trajectory_[i].T_world_cam;
  sink_.poses_corrected(correction, before_frame);
}

Result<ScanSession::Saved> ScanSession::stop(const std::string& reason,
                                             const FusionProgress& progress) {
  if (!active()) return invalid_argument("no scan is running");
  // What the loop closer has found last moves the poses and the map before they are saved.
  if (const std::optional<AppliedCorrection> last = path_->finish())
    correct_trajectory(*last, reconstructor_->next_frame_id());
  const size_t removed = reconstructor_->finish();
  sink_.keep_graph(path_->checkpoint_state());
  Saved saved;
  saved.store = sink_.end_scan(reason, *reconstructor_, progress);

  const std::string base = (std::filesystem::path(scan_.scan_dir) / scan_.scan_id).string();
  const std::string ply_path = base + ".ply";
  const std::string tum_path = base + "-trajectory.txt";
  std::error_code ec;
  std::filesystem::create_directories(scan_.scan_dir, ec);
  size_t points = 0;
  DF_RETURN_IF_ERROR(write_atomically(ply_path, [&](const std::string& p) -> Status {
                       auto written = sink_.write_cloud(p, *reconstructor_);
                       if (!written) return written.status();
                       points = *written;
                       return Status::ok();
                     }).with_context("saving scan " + scan_.scan_id));
  DF_RETURN_IF_ERROR(write_atomically(tum_path, [&](const std::string& p) {
                       return write_tum_trajectory(p, trajectory_);
                     }).with_context("saving scan " + scan_.scan_id));
  saved.message = "scan " + scan_.scan_id + " saved: " + std::to_string(points) + " points (" +
                  std::to_string(removed) + " removed by the post-filter) in " + ply_path + ", " +
                  std::to_string(trajectory_.size()) + " poses in " + tum_path;
  if (!saved.store.is_ok()) saved.message += "; checkpoint store: " + saved.store.to_string();
  DF_LOG(Fusion, Info) << saved.message;
  path_.reset();
  reconstructor_.reset();
  trajectory_.clear();
  trajectory_frames_.clear();
  trajectory_sequences_.clear();
  return saved;
}

}  // namespace depthfuse::fusiond
