// The map preview (see map_preview.hpp). Everything but on_request() and add_counters() runs on
// the fusion worker.
#include "map_preview.hpp"

#include <algorithm>
#include <cmath>

#include "depthfuse/base/clock.hpp"
#include "depthfuse/base/log.hpp"
#include "depthfuse/daemon/moving_average.hpp"
#include "depthfuse/lcm/channels.hpp"
#include "depthfuse/lcm/frame_codec.hpp"
#include "depthfuse/map_request_t.hpp"

DF_LOG_CATEGORY(MapPreview)

namespace depthfuse::fusiond {

namespace {

// A delta is split into messages of about this size: a lost UDP fragment then costs one piece,
// and a viewer's decoder never holds more than this at once.
constexpr size_t kMessageBytes = 256 * 1024;
// Chunk positions are offsets from the chunk's centre in chunk_size / kPositionSteps: 8 µm for
// 0.5 m chunks, and int16 covers the chunk whatever its size.
constexpr float kPositionSteps = 60000.0f;
constexpr float kUncertaintyUnitM = 1e-5f;  // 10 µm; int16 saturates at 0.33 m
// Cells per chunk edge at most (finer cells are taken as this): the per-cell scratch stays at
// 64^3 entries.
constexpr int kMaxCellsPerAxis = 64;

size_t chunk_wire_bytes(const depthfuse::map_chunk_t& c) {
  return 4 * 3 + 4 + 4 + 4 + 4 + c.position.size() * 2 + c.normal.size() + c.uncertainty.size() * 2 +
         4 + c.rgb.size();
}

int16_t saturate16(float v) {
  return static_cast<int16_t>(std::lround(std::clamp(v, -32767.0f, 32767.0f)));
}

}  // namespace

MapPreview::MapPreview(const MapPreviewConfig& config, std::string sender, lcm::LcmTransport* lcm)
    : config_(config), sender_(std::move(sender)), lcm_(lcm) {}

void MapPreview::on_request(const uint8_t* data, size_t size, lcm::ReceiveCounters* counters) {
  depthfuse::map_request_t req;
  const auto r = lcm::decode_message(data, size, &req);
  if (r != lcm::DecodeResult::kOk) {
    counters->count(r);
    return;
  }
  if (!req.target.empty() && req.target != sender_) return;
  ++requests_;
  // Several requests before the next delta are answered by one snapshot (the newest id).
  requested_snapshot_ = req.request_id == 0 ? 1 : req.request_id;
}

void MapPreview::frame_fused(int64_t sequence, const Pose& T_world_cam, bool registered) {
  has_pose_ = true;
  registered_ = registered;
  frame_sequence_ = sequence;
  T_world_cam_ = T_world_cam;
}

void MapPreview::restart(const std::string& scan_id, const IncrementalReconstructor* reconstructor) {
  scan_id_ = scan_id;
  reconstructor_ = reconstructor;
  scanned_through_frame_ = 0;
  pending_.clear();
  queued_.clear();
  snapshot_left_.clear();
  has_pose_ = false;
  registered_ = false;
  tracking_ = 0;
  frame_sequence_ = 0;
}

void MapPreview::queue(const ChunkKey& key) {
  if (queued_.insert(key).second) pending_.push_back(key);
}

size_t MapPreview::decimate(const ChunkKey& key, const Chunk& chunk, float chunk_size_m,
                            depthfuse::map_chunk_t* out) {
  const PointArrays& a = chunk.points();
  const int cells = std::clamp(static_cast<int>(std::ceil(chunk_size_m / config_.cell_size_m)), 1,
                               kMaxCellsPerAxis);
  const float inv_cell = static_cast<float>(cells) / chunk_size_m;
  const Eigen::Vector3f origin(key.x * chunk_size_m, key.y * chunk_size_m, key.z * chunk_size_m);
  const Eigen::Vector3f centre = origin + Eigen::Vector3f::Constant(0.5f * chunk_size_m);
  const float target = static_cast<float>(config_.target_uncertainty_m);

  cells_.resize(static_cast<size_t>(cells) * cells * cells);
  if (++generation_ == 0) {  // wrapped: every stamp is stale again
    for (Cell& c : cells_) c.generation = 0;
    generation_ = 1;
  }
  occupied_.clear();
  size_t covered = 0;
  for (size_t i = 0; i < a.size(); ++i) {
    const Eigen::Vector3f local = (a.position_m[i] - origin) * inv_cell;
    int c[3];
    for (int k = 0; k < 3; ++k) c[k] = std::clamp(static_cast<int>(local[k]), 0, cells - 1);
    const uint32_t id = static_cast<uint32_t>((c[0] * cells + c[1]) * cells + c[2]);
    const float u = uncertainty_m(a, i);
    covered += u < target;
    Cell& cell = cells_[id];
    if (cell.generation != generation_) {
      cell = Cell{generation_, static_cast<uint32_t>(i), u};
      occupied_.push_back(id);
    } else if (u < cell.best_u) {  // the most certain point of the cell stands for it
      cell.best = static_cast<uint32_t>(i);
      cell.best_u = u;
    }
  }

  out->key[0] = key.x;
  out->key[1] = key.y;
  out->key[2] = key.z;
  out->map_points = static_cast<int32_t>(a.size());
  out->coverage = a.empty() ? 0.0f : static_cast<float>(covered) / static_cast<float>(a.size());
  const size_t n = occupied_.size();
  out->position.resize(3 * n);
  out->normal.resize(3 * n);
  out->uncertainty.resize(n);
  out->rgb.resize(3 * n);
  bool any_colour = false;
  const float inv_unit = kPositionSteps / chunk_size_m;
  for (size_t j = 0; j < n; ++j) {
    const Cell& cell = cells_[occupied_[j]];
    const Eigen::Vector3f offset = (a.position_m[cell.best] - centre) * inv_unit;
    const PointState& s = a.state[cell.best];
    const float normal[3] = {s.nx, s.ny, s.nz};
    const uint8_t rgb[3] = {s.r, s.g, s.b};
    for (int k = 0; k < 3; ++k) {
      out->position[3 * j + k] = saturate16(offset[k]);
      out->normal[3 * j + k] = static_cast<int8_t>(std::lround(std::clamp(normal[k], -1.0f, 1.0f) * 127));
      out->rgb[3 * j + k] = rgb[k];
    }
    any_colour = any_colour || s.r || s.g || s.b;
    out->uncertainty[j] = std::isfinite(cell.best_u) ? saturate16(cell.best_u / kUncertaintyUnitM)
                                                     : int16_t{32767};
  }
  if (!any_colour) out->rgb.clear();
  out->num_points = static_cast<int32_t>(n);
  out->num_coords = static_cast<int32_t>(3 * n);
  out->num_rgb = static_cast<int32_t>(out->rgb.size());
  return a.size();
}

depthfuse::map_delta_t MapPreview::header(int8_t state, const std::string& scan_id,
                                          const IncrementalReconstructor* reconstructor) const {
  depthfuse::map_delta_t msg;
  msg.protocol_version = depthfuse::map_delta_t::PROTOCOL_VERSION;
  msg.sender = sender_;
  msg.scan_id = scan_id;
  msg.kind = snapshot_id_ != 0 ? depthfuse::map_delta_t::KIND_SNAPSHOT
                               : depthfuse::map_delta_t::KIND_DELTA;
  msg.snapshot_request_id = snapshot_id_;
  msg.snapshot_complete = false;
  msg.state = state;
  msg.has_pose = has_pose_;
  msg.registered = registered_;
  msg.tracking = tracking_;
  msg.frame_sequence = frame_sequence_;
  lcm::pose_to_arrays(T_world_cam_, msg.position_m, msg.orientation_wxyz);
  msg.map_points = 0;
  const float chunk_size_m =
      reconstructor ? static_cast<float>(reconstructor->map().chunk_size_m()) : 0.0f;
  msg.chunk_size_m = chunk_size_m;
  msg.cell_size_m = static_cast<float>(config_.cell_size_m);
  msg.position_unit_m = chunk_size_m / kPositionSteps;
  msg.uncertainty_unit_m = kUncertaintyUnitM;
  msg.target_uncertainty_m = static_cast<float>(config_.target_uncertainty_m);
  msg.num_chunks = 0;
  return msg;
}

void MapPreview::publish(depthfuse::map_delta_t* msg) {
  msg->utime = now_utime();
  msg->sequence = ++sequence_;
  msg->num_chunks = static_cast<int32_t>(msg->chunks.size());
  msg->chunks_pending = static_cast<int32_t>(pending_.size());
  if (auto st = lcm_->publish_message(lcm::kMapChannel, *msg); !st.is_ok()) {
    DF_LOG(MapPreview, Warning) << "map delta not sent: " << st.to_string();
    return;
  }
  const int64_t bytes = msg->getEncodedSize();
  bytes_sent_ += bytes;
  ++messages_sent_;
  tokens_bytes_ -= static_cast<double>(bytes);
}

void MapPreview::tick(int8_t state, const std::string& scan_id,
                      const IncrementalReconstructor* reconstructor) {
  if (!config_.enabled) return;
  const auto now = Clock::now();
  if (now < next_delta_) return;
  const int64_t started_ns = steady_ns();
  const auto period = std::chrono::duration_cast<Clock::duration>(
      std::chrono::duration<double>(1.0 / config_.rate_hz));
  next_delta_ = next_delta_ == Clock::time_point{} || now - next_delta_ > period ? now + period
                                                                                 : next_delta_ + period;
  // The bucket holds at most one period's worth, so a quiet spell is no licence for a burst.
  const double cap = config_.max_bytes_per_s;
  const double refill_s =
      last_refill_ == Clock::time_point{} ? 1.0 / config_.rate_hz
                                          : std::chrono::duration<double>(now - last_refill_).count();
  last_refill_ = now;
  tokens_bytes_ = std::min(cap / config_.rate_hz, tokens_bytes_ + cap * refill_s);
  const int64_t bytes_before = bytes_sent_.load();

  if (scan_id != scan_id_ || reconstructor != reconstructor_) restart(scan_id, reconstructor);
  const int64_t request = requested_snapshot_.exchange(0);
  if (request != 0) {
    snapshot_id_ = request;
    ++snapshots_;
  }

  depthfuse::map_delta_t msg = header(state, scan_id, reconstructor);
  if (reconstructor) {
    const PointMap& map = reconstructor->map();
    msg.map_points = static_cast<int64_t>(reconstructor->map().point_count());
    // The chunk table's headers only: chunks touched after the last look are due.
    const uint32_t through = reconstructor->next_frame_id() - 1;
    const uint32_t after = scanned_through_frame_;
    map.for_each_chunk([&](const ChunkKey& key, const Chunk& c) {
      if (request != 0) snapshot_left_.insert(key);
      if (request != 0 || c.last_touched_frame > after) queue(key);
    });
    scanned_through_frame_ = through;

    const float chunk_size_m = static_cast<float>(map.chunk_size_m());
    size_t points_read = 0, msg_bytes = 0;
    // The bytes gathered but not yet published still count against the bucket; publish() takes
    // each message's exact size from it.
    while (!pending_.empty() && tokens_bytes_ > static_cast<double>(msg_bytes) &&
           points_read < static_cast<size_t>(config_.max_points_per_delta)) {
      const ChunkKey key = pending_.front();
      pending_.pop_front();
      queued_.erase(key);
      // The queue is first in, first out and holds a key once: every chunk of a snapshot goes
      // out within one pass, however busy the scan keeps the others.
      snapshot_left_.erase(key);
      const Chunk* chunk = map.find(key);
      if (!chunk || chunk->points().empty()) continue;  // evicted or emptied since it was queued
      msg.chunks.emplace_back();
      points_read += decimate(key, *chunk, chunk_size_m, &msg.chunks.back());
      msg_bytes += chunk_wire_bytes(msg.chunks.back());
      if (msg_bytes >= kMessageBytes) {
        publish(&msg);
        msg.chunks.clear();
        msg_bytes = 0;
      }
    }
  } else {
    pending_.clear();
    queued_.clear();
    snapshot_left_.clear();
  }
  if (snapshot_id_ != 0 && snapshot_left_.empty()) {
    msg.snapshot_complete = true;
    snapshot_id_ = 0;
  }
  // One message a period at least: it carries the pose and state even when nothing changed.
  publish(&msg);

  chunks_pending_ = static_cast<int64_t>(pending_.size());
  daemon::ewma(&bytes_per_s_, static_cast<double>(bytes_sent_.load() - bytes_before) * config_.rate_hz);
  const double ms = (steady_ns() - started_ns) * 1e-6;
  daemon::ewma(&tick_ms_mean_, ms);
  tick_ms_max_ = std::max(tick_ms_max_.load(), ms);
  tick_ms_total_ = tick_ms_total_.load() + ms;
}

void MapPreview::add_counters(std::vector<std::pair<std::string, double>>* out) const {
  out->emplace_back("map_preview_cap_bytes_per_s", config_.enabled ? config_.max_bytes_per_s : 0.0);
  out->emplace_back("map_preview_bytes_per_s", bytes_per_s_.load());
  out->emplace_back("map_preview_bytes", static_cast<double>(bytes_sent_.load()));
  out->emplace_back("map_preview_messages", static_cast<double>(messages_sent_.load()));
  out->emplace_back("map_preview_chunks_pending", static_cast<double>(chunks_pending_.load()));
  out->emplace_back("map_preview_requests", static_cast<double>(requests_.load()));
  out->emplace_back("map_preview_snapshots", static_cast<double>(snapshots_.load()));
  out->emplace_back("map_preview_ms_mean", tick_ms_mean_.load());
  out->emplace_back("map_preview_ms_max", tick_ms_max_.load());
  out->emplace_back("map_preview_ms_total", tick_ms_total_.load());
}

}  // namespace depthfuse::fusiond
