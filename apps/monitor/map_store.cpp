#include "map_store.hpp"

#include <cmath>
#include <cstring>

#include "depthfuse/daemon/status_json.hpp"
#include "depthfuse/lcm/frame_codec.hpp"
#include "keyframe_motions.hpp"

namespace depthfuse::monitor {

namespace {

constexpr uint32_t kChunkMagic = 0x4b484344;  // "DCHK" little-endian
constexpr size_t kMaxTrajectoryPoses = 100000;
constexpr float kMinPoseStepM = 0.005f;  // closer poses add nothing to the drawn path

template <typename T>
void put(std::vector<uint8_t>* out, T v) {
  const size_t at = out->size();
  out->resize(at + sizeof(T));
  std::memcpy(out->data() + at, &v, sizeof(T));
}

bool well_formed(const depthfuse::map_chunk_t& c) {
  return c.num_points >= 0 && c.num_coords == 3 * c.num_points &&
         c.position.size() == static_cast<size_t>(c.num_coords) &&
         c.normal.size() == static_cast<size_t>(c.num_coords) &&
         c.uncertainty.size() == static_cast<size_t>(c.num_points) &&
         (c.num_rgb == 0 || c.num_rgb == c.num_coords) &&
         c.rgb.size() == static_cast<size_t>(c.num_rgb) && std::isfinite(c.coverage);
}

// The browser's layout, little-endian, every array 4-byte aligned: u32 magic, i32 key[3],
// f32 centre[3], f32 coverage, u32 n, u32 flags (1: rgb), f32 xyz[3n] (world, m),
// f32 uncertainty[n] (m), then if flags & 1 u8 rgb[3n] padded to 4.
std::vector<uint8_t> pack(const depthfuse::map_chunk_t& c, const depthfuse::map_delta_t& msg) {
  std::vector<uint8_t> out;
  const size_t n = static_cast<size_t>(c.num_points);
  out.reserve(40 + n * 16 + (c.num_rgb > 0 ? (3 * n + 3) / 4 * 4 : 0));
  const float s = msg.chunk_size_m;
  const float centre[3] = {(c.key[0] + 0.5f) * s, (c.key[1] + 0.5f) * s, (c.key[2] + 0.5f) * s};
  put(&out, kChunkMagic);
  for (int k = 0; k < 3; ++k) put(&out, c.key[k]);
  for (int k = 0; k < 3; ++k) put(&out, centre[k]);
  put(&out, c.coverage);
  put(&out, static_cast<uint32_t>(n));
  put(&out, static_cast<uint32_t>(c.num_rgb > 0 ? 1 : 0));
  for (size_t i = 0; i < 3 * n; ++i) put(&out, centre[i % 3] + c.position[i] * msg.position_unit_m);
  for (size_t i = 0; i < n; ++i) put(&out, c.uncertainty[i] * msg.uncertainty_unit_m);
  if (c.num_rgb > 0) {
    out.insert(out.end(), c.rgb.begin(), c.rgb.end());
    out.resize((out.size() + 3) / 4 * 4, 0);
  }
  return out;
}

}  // namespace

MapStore::Accepted MapStore::apply(const depthfuse::map_delta_t& msg, bool* want_snapshot) {
  if (!(msg.chunk_size_m >= 0 && std::isfinite(msg.chunk_size_m) &&
        std::isfinite(msg.position_unit_m) && std::isfinite(msg.uncertainty_unit_m)))
    return Accepted::kMalformed;
  std::lock_guard<std::mutex> lock(mutex_);
  *want_snapshot = false;
  // Between scans (no scan id) the last scan's map stays on the pages; another scan or another
  // fusion daemon starts a new map.
  if (msg.sender != sender_ || (!msg.scan_id.empty() && msg.scan_id != scan_id_)) {
    // Pages start over, and the monitor asks for the whole of the new map.
    ++epoch_;
    sender_ = msg.sender;
    scan_id_ = msg.scan_id;
    chunks_.clear();
    by_version_.clear();
    trajectory_.clear();
    trajectory_sequence_.clear();
    correction_ = 0;
    correction_json_.clear();
    bytes_ = points_ = 0;
    *want_snapshot = !msg.scan_id.empty();
  } else if (msg.sequence != last_sequence_ + 1 && !msg.scan_id.empty()) {
    *want_snapshot = true;  // missed deltas (or the fusion daemon restarted)
  }
  last_sequence_ = msg.sequence;

  Accepted result = Accepted::kOk;
  for (const auto& c : msg.chunks) {
    if (!well_formed(c)) {
      result = Accepted::kMalformed;
      continue;
    }
    const Key key{c.key[0], c.key[1], c.key[2]};
    Entry& e = chunks_[key];
    if (e.packed) {
      by_version_.erase(e.version);
      bytes_ -= e.packed->size();
      points_ -= e.points;
    }
    auto packed = std::make_shared<const std::vector<uint8_t>>(pack(c, msg));
    e.version = ++version_;
    bytes_ += packed->size();
    points_ += static_cast<size_t>(c.num_points);
    e.points = static_cast<size_t>(c.num_points);
    e.packed = std::move(packed);
    by_version_[e.version] = key;
  }
  // Over the budget: the chunks unchanged for longest go (pages keep what they have).
  while (bytes_ > max_bytes_ && !by_version_.empty()) {
    auto oldest = by_version_.begin();
    auto it = chunks_.find(oldest->second);
    bytes_ -= it->second.packed->size();
    points_ -= it->second.points;
    chunks_.erase(it);
    by_version_.erase(oldest);
  }

  if (msg.has_pose) {
    const float p[3] = {static_cast<float>(msg.position_m[0]), static_cast<float>(msg.position_m[1]),
                        static_cast<float>(msg.position_m[2])};
    const size_t n = trajectory_.size();
    const bool moved = n < 3 || std::hypot(p[0] - trajectory_[n - 3], p[1] - trajectory_[n - 2],
                                           p[2] - trajectory_[n - 1]) >= kMinPoseStepM;
    if (moved && n / 3 < kMaxTrajectoryPoses) {
      trajectory_.insert(trajectory_.end(), p, p + 3);
      trajectory_sequence_.push_back(msg.frame_sequence);
    }
  }
  last_ = msg;
  last_.chunks.clear();
  last_.num_chunks = 0;
  have_last_ = true;
  pose_json_ = pose_json();  // once per delta, for every page and push
  ++pose_version_;
  return result;
}

MapStore::Accepted MapStore::apply(const depthfuse::graph_correction_t& msg, Status* problem) {
  auto motions = KeyframeMotions::from_message(msg);
  if (!motions) {
    *problem = motions.status();
    return Accepted::kMalformed;
  }
  std::lock_guard<std::mutex> lock(mutex_);
  if (msg.scan_id.empty() || msg.scan_id != scan_id_ || msg.sender != sender_) {
    *problem = invalid_argument("graph correction for scan '" + msg.scan_id + "' of '" + msg.sender +
                                "', while the map is scan '" + scan_id_ + "' of '" + sender_ + "'");
    return Accepted::kOtherScan;
  }
  size_t moved = 0;
  for (size_t i = 0; i < trajectory_sequence_.size(); ++i) {
    const Pose* motion = motions->of(trajectory_sequence_[i]);
    if (!motion) continue;
    float* p = &trajectory_[3 * i];
    const Eigen::Vector3d q = *motion * Eigen::Vector3d(p[0], p[1], p[2]);
    for (int k = 0; k < 3; ++k) p[k] = static_cast<float>(q[k]);
    ++moved;
  }
  // The camera moves too, so that the frustum stays at the end of the path until the next delta.
  if (have_last_ && last_.has_pose) {
    if (const Pose* motion = motions->of(last_.frame_sequence)) {
      auto T_world_cam = lcm::pose_from_arrays(last_.position_m, last_.orientation_wxyz);
      if (T_world_cam) {
        lcm::pose_to_arrays(*motion * *T_world_cam, last_.position_m, last_.orientation_wxyz);
        pose_json_ = pose_json();
        ++pose_version_;
      }
    }
  }
  ++path_version_;
  ++correction_;
  using daemon::json_number;
  correction_json_ = "{\"type\": \"correction\", \"version\": " + std::to_string(msg.version) +
                     ", \"loops\": " + std::to_string(msg.loops) +
                     ", \"keyframes\": " + std::to_string(msg.num_keyframes) +
                     ", \"max_translation_m\": " + json_number(msg.max_translation_m) +
                     ", \"poses_moved\": " + std::to_string(moved) + "}";
  return Accepted::kOk;
}

std::string MapStore::pose_json() const {
  using daemon::json_number;
  using daemon::json_string;
  const auto& m = last_;
  std::string j = "{\"type\": \"pose\", \"sender\": " + json_string(m.sender) +
                  ", \"scan_id\": " + json_string(m.scan_id) + ", \"state\": " +
                  std::to_string(m.state) + ", \"has_pose\": " + (m.has_pose ? "true" : "false") +
                  ", \"registered\": " + (m.registered ? "true" : "false") +
                  ", \"tracking\": " + std::to_string(static_cast<int>(m.tracking)) +
                  ", \"frame_sequence\": " + std::to_string(m.frame_sequence) + ", \"position_m\": [";
  for (int k = 0; k < 3; ++k) j += (k ? ", " : "") + json_number(m.position_m[k]);
  j += "], \"orientation_wxyz\": [";
  for (int k = 0; k < 4; ++k) j += (k ? ", " : "") + json_number(m.orientation_wxyz[k]);
  j += "], \"map_points\": " + std::to_string(m.map_points) +
       ", \"chunks_pending\": " + std::to_string(m.chunks_pending) +
       ", \"preview_points\": " + std::to_string(points_) +
       ", \"preview_chunks\": " + std::to_string(chunks_.size()) +
       ", \"cell_size_m\": " + json_number(m.cell_size_m) +
       ", \"chunk_size_m\": " + json_number(m.chunk_size_m) +
       ", \"target_uncertainty_m\": " + json_number(m.target_uncertainty_m) + "}";
  return j;
}

void MapStore::changes(Cursor* cursor, size_t max_bytes, std::vector<std::string>* text,
                       std::vector<std::shared_ptr<const std::vector<uint8_t>>>* chunks) const {
  std::lock_guard<std::mutex> lock(mutex_);
  if (cursor->epoch != epoch_) {
    text->push_back("{\"type\": \"reset\", \"scan_id\": " + daemon::json_string(scan_id_) + "}");
    // A new page, or a new map: the path it gets is already corrected, and so no note.
    *cursor = Cursor{epoch_, 0, 0, 0, path_version_, correction_};
  }
  if (have_last_ && cursor->pose_version != pose_version_) {
    text->push_back(pose_json_);
    cursor->pose_version = pose_version_;
  }
  if (cursor->path_version != path_version_) {
    cursor->path_version = path_version_;
    cursor->trajectory = 0;  // a correction moved the path: all of it again
  }
  if (cursor->trajectory < trajectory_.size()) {
    std::string j = "{\"type\": \"trajectory\", \"from\": " + std::to_string(cursor->trajectory / 3) +
                    ", \"xyz\": [";
    for (size_t i = cursor->trajectory; i < trajectory_.size(); ++i)
      j += (i > cursor->trajectory ? ", " : "") + daemon::json_number(trajectory_[i]);
    text->push_back(j + "]}");
    cursor->trajectory = trajectory_.size();
  }
  if (cursor->correction != correction_) {
    text->push_back(correction_json_);
    cursor->correction = correction_;
  }
  size_t bytes = 0;
  for (auto it = by_version_.upper_bound(cursor->version); it != by_version_.end(); ++it) {
    if (bytes >= max_bytes) break;
    const Entry& e = chunks_.at(it->second);
    chunks->push_back(e.packed);
    bytes += e.packed->size();
    cursor->version = it->first;
  }
}

size_t MapStore::chunk_count() const {
  std::lock_guard<std::mutex> lock(mutex_);
  return chunks_.size();
}

size_t MapStore::point_count() const {
  std::lock_guard<std::mutex> lock(mutex_);
  return points_;
}

}  // namespace depthfuse::monitor
