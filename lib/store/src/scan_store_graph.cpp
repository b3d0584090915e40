// The pose graph in the scan file (schema 6): its keyframes, each once with the odometry edge to
// the one before and its cloud (graph_keyframes), and the one row of what corrections change (the
// keyframes' poses, the loop edges, the version, the map deformation's history: `graph`); and the
// stored poses moved by a correction. Written inside a checkpoint, on the connection's thread;
// read by a resume and by inspect. Layouts: docs/checkpoint-format.md, "The pose graph".
#include <algorithm>
#include <cstring>
#include <tuple>

#include "depthfuse/store/checksum.hpp"
#include "scan_store_internal.hpp"

namespace depthfuse::store {

namespace {

constexpr size_t kPoseBytes = 12 * sizeof(double);    // encode_pose's
constexpr size_t kMatrixBytes = 36 * sizeof(double);  // a 6x6 matrix, column-major
constexpr size_t kThumbnailFloats = std::tuple_size<decltype(KeyframeCloud::thumbnail)>::value;

// Little-endian values appended to a byte string, and read back with bounds checked.
class Bytes {
 public:
  template <typename T>
  void put(T v) {
    const auto* p = reinterpret_cast<const uint8_t*>(&v);
    out_.insert(out_.end(), p, p + sizeof(T));
  }
  void pose(const Pose& T) {
    const std::vector<uint8_t> b = encode_pose(T);
    out_.insert(out_.end(), b.begin(), b.end());
  }
  void matrix(const Matrix6d& m) {
    const auto* p = reinterpret_cast<const uint8_t*>(m.data());
    out_.insert(out_.end(), p, p + kMatrixBytes);
  }
  std::vector<uint8_t>& bytes() { return out_; }

 private:
  std::vector<uint8_t> out_;
};

class Reader {
 public:
  Reader(const uint8_t* p, size_t n, std::string what) : p_(p), n_(n), what_(std::move(what)) {}
  template <typename T>
  Status get(T* v) {
    DF_RETURN_IF_ERROR(need(sizeof(T)));
    std::memcpy(v, p_ + at_, sizeof(T));
    at_ += sizeof(T);
    return Status::ok();
  }
  Status pose(Pose* T) {
    DF_RETURN_IF_ERROR(need(kPoseBytes));
    DF_RETURN_IF_ERROR(decode_pose(p_ + at_, kPoseBytes, what_, T));
    at_ += kPoseBytes;
    return Status::ok();
  }
  Status matrix(Matrix6d* m) {
    DF_RETURN_IF_ERROR(need(kMatrixBytes));
    std::memcpy(m->data(), p_ + at_, kMatrixBytes);
    at_ += kMatrixBytes;
    if (!m->allFinite()) return corrupt(what_ + ": a matrix that is not finite");
    return Status::ok();
  }
  // A count of items of at least `item_bytes` each, which the rest must be able to hold.
  Status count(uint32_t* n, size_t item_bytes) {
    DF_RETURN_IF_ERROR(get(n));
    if (static_cast<uint64_t>(*n) * item_bytes > n_ - at_)
      return corrupt(what_ + ": announces " + std::to_string(*n) + " items in " +
                     std::to_string(n_ - at_) + " bytes");
    return Status::ok();
  }
  bool at_end() const { return at_ == n_; }
  Status done() const {
    if (at_ != n_) return corrupt(what_ + ": " + std::to_string(n_ - at_) + " bytes left over");
    return Status::ok();
  }

 private:
  Status need(size_t k) const {
    if (n_ - at_ < k) return corrupt(what_ + ": truncated");
    return Status::ok();
  }
  const uint8_t* p_;
  size_t n_, at_ = 0;
  std::string what_;
};

// What a correction rewrites: the keyframes' poses, the loop edges, the deformation's history.
std::vector<uint8_t> encode_state(const GraphCheckpoint& g) {
  Bytes b;
  b.put(static_cast<uint32_t>(g.graph.keyframes.size()));
  for (const GraphKeyframe& k : g.graph.keyframes) b.pose(k.T_world_kf);
  b.put(static_cast<uint32_t>(g.graph.loops.size()));
  for (const PoseGraphEdge& e : g.graph.loops) {
    b.put(e.from);
    b.put(e.to);
    b.pose(e.T_from_to);
    b.matrix(e.information);
  }
  const DeformationHistory& h = g.deformation;
  b.put(static_cast<uint32_t>(h.keyframe_first_frame.size()));
  for (const uint32_t f : h.keyframe_first_frame) b.put(f);
  b.put(h.oldest_version);
  b.put(static_cast<uint32_t>(h.T_world_kf.size()));
  for (size_t v = 0; v < h.T_world_kf.size(); ++v) {
    b.put(static_cast<uint32_t>(h.T_world_kf[v].size()));
    for (const Pose& T : h.T_world_kf[v]) b.pose(T);
    b.put(h.max_motion_m[v]);
  }
  // The merge passes queued (schema 8; a blob written before ends above).
  b.put(static_cast<uint32_t>(h.merges.size()));
  for (const DeformationHistory::QueuedMerge& m : h.merges) {
    b.put(m.key.x);
    b.put(m.key.y);
    b.put(m.key.z);
    b.put(m.first_point);
    b.put(m.from_version);
  }
  return std::move(b.bytes());
}

// Into g: the keyframes' poses (g->graph.keyframes sized by the caller's rows or, when empty,
// made here), the loops and the history.
Status decode_state(const std::vector<uint8_t>& bytes, const std::string& what,
                    GraphCheckpoint* g) {
  Reader r(bytes.data(), bytes.size(), what);
  uint32_t n = 0;
  DF_RETURN_IF_ERROR(r.count(&n, kPoseBytes));
  if (g->graph.keyframes.empty()) g->graph.keyframes.resize(n);
  if (n != g->graph.keyframes.size())
    return corrupt(what + ": " + std::to_string(n) + " keyframe poses for " +
                   std::to_string(g->graph.keyframes.size()) + " keyframes");
  for (GraphKeyframe& k : g->graph.keyframes) DF_RETURN_IF_ERROR(r.pose(&k.T_world_kf));
  DF_RETURN_IF_ERROR(r.count(&n, 8 + kPoseBytes + kMatrixBytes));
  g->graph.loops.resize(n);
  for (PoseGraphEdge& e : g->graph.loops) {
    DF_RETURN_IF_ERROR(r.get(&e.from));
    DF_RETURN_IF_ERROR(r.get(&e.to));
    DF_RETURN_IF_ERROR(r.pose(&e.T_from_to));
    DF_RETURN_IF_ERROR(r.matrix(&e.information));
    e.kind = PoseGraphEdge::Kind::kLoop;
  }
  DeformationHistory& h = g->deformation;
  DF_RETURN_IF_ERROR(r.count(&n, sizeof(uint32_t)));
  h.keyframe_first_frame.resize(n);
  for (uint32_t& f : h.keyframe_first_frame) DF_RETURN_IF_ERROR(r.get(&f));
  DF_RETURN_IF_ERROR(r.get(&h.oldest_version));
  DF_RETURN_IF_ERROR(r.count(&n, sizeof(uint32_t) + sizeof(double)));
  h.T_world_kf.resize(n);
  h.max_motion_m.resize(n);
  for (uint32_t v = 0; v < n; ++v) {
    uint32_t m = 0;
    DF_RETURN_IF_ERROR(r.count(&m, kPoseBytes));
    h.T_world_kf[v].resize(m);
    for (Pose& T : h.T_world_kf[v]) DF_RETURN_IF_ERROR(r.pose(&T));
    DF_RETURN_IF_ERROR(r.get(&h.max_motion_m[v]));
  }
  h.merges.clear();
  if (r.at_end()) return Status::ok();  // written before schema 8: no merges kept
  DF_RETURN_IF_ERROR(r.count(&n, 5 * sizeof(uint32_t)));
  h.merges.resize(n);
  for (DeformationHistory::QueuedMerge& m : h.merges) {
    DF_RETURN_IF_ERROR(r.get(&m.key.x));
    DF_RETURN_IF_ERROR(r.get(&m.key.y));
    DF_RETURN_IF_ERROR(r.get(&m.key.z));
    DF_RETURN_IF_ERROR(r.get(&m.first_point));
    DF_RETURN_IF_ERROR(r.get(&m.from_version));
  }
  return r.done();
}

// A keyframe's cloud as one column of floats: positions (x y z each), normals, the thumbnail.
Status encode_cloud(BlobCodec& codec, const KeyframeCloud& c, std::vector<uint8_t>* blob) {
  std::vector<float> v;
  v.reserve(6 * c.size() + kThumbnailFloats);
  for (const Eigen::Vector3f& p : c.position_m) v.insert(v.end(), p.data(), p.data() + 3);
  for (const Eigen::Vector3f& n : c.normal) v.insert(v.end(), n.data(), n.data() + 3);
  v.insert(v.end(), c.thumbnail.begin(), c.thumbnail.end());
  return codec.encode_column(BlobKind::kKeyframeCloud, v.data(), static_cast<uint32_t>(v.size()),
                             sizeof(float), blob);
}

Status decode_cloud(BlobCodec& codec, const void* blob, size_t size, const std::string& what,
                    KeyframeCloud* c) {
  std::vector<uint8_t> bytes;
  DF_RETURN_IF_ERROR(
      codec.decode_column(blob, size, what, BlobKind::kKeyframeCloud, sizeof(float), &bytes));
  const size_t floats = bytes.size() / sizeof(float);
  if (floats < kThumbnailFloats || (floats - kThumbnailFloats) % 6 != 0)
    return corrupt(what + ": " + std::to_string(floats) + " values are not points and a thumbnail");
  const size_t n = (floats - kThumbnailFloats) / 6;
  const auto* f = reinterpret_cast<const float*>(bytes.data());
  c->position_m.resize(n);
  c->normal.resize(n);
  for (size_t i = 0; i < n; ++i) {
    c->position_m[i] = Eigen::Vector3f(f[3 * i], f[3 * i + 1], f[3 * i + 2]);
    c->normal[i] = Eigen::Vector3f(f[3 * (n + i)], f[3 * (n + i) + 1], f[3 * (n + i) + 2]);
  }
  std::memcpy(c->thumbnail.data(), f + 6 * n, kThumbnailFloats * sizeof(float));
  return Status::ok();
}

// graph_keyframes.checksum: keyframe u32, frame_id u32, utime i64, the odometry blob's length u32
// and bytes (0 and none for keyframe 0), the cloud blob's length u32 and bytes.
uint32_t graph_keyframe_checksum(uint32_t keyframe, uint32_t frame_id, int64_t utime,
                                 const void* odometry, size_t odometry_size, const void* cloud,
                                 size_t cloud_size) {
  return RowCrc()
      .add(keyframe).add(frame_id).add(utime)
      .add(static_cast<uint32_t>(odometry_size)).bytes(odometry, odometry_size)
      .add(static_cast<uint32_t>(cloud_size)).bytes(cloud, cloud_size)
      .value();
}

// graph.checksum: checkpoint_id i64, version u32, keyframe_count u32, the state blob's length u32
// and bytes.
uint32_t graph_row_checksum(int64_t checkpoint_id, uint32_t version, uint32_t keyframe_count,
                            const void* state, size_t state_size) {
  return RowCrc()
      .add(checkpoint_id).add(version).add(keyframe_count)
      .add(static_cast<uint32_t>(state_size)).bytes(state, state_size)
      .value();
}

constexpr const char* kGraphRow =
    "SELECT checkpoint_id, version, keyframe_count, checksum, state FROM graph WHERE id = 1;";

// The graph row, its checksum checked and its state blob decoded into *g (poses into the
// keyframes g holds, or as many as it announces).
Status read_graph_row(ScanStore::Impl& s, GraphCheckpoint* g, GraphSummary* summary, bool* found) {
  const std::string what = s.path + ": pose graph";
  auto st = s.db.prepare(kGraphRow, "reading the pose graph");
  if (!st) return st.status();
  auto row = st->step();
  if (!row) return row.status();
  *found = *row;
  if (!*row) return Status::ok();
  const sql::Row r = st->row();
  summary->checkpoint_id = r.int64(0);
  const int64_t version = r.int64(1), count = r.int64(2);
  if (version < 0 || version > UINT32_MAX || count < 0 || count > UINT32_MAX)
    return corrupt(what + ": version " + std::to_string(version) + " or keyframe count " +
                   std::to_string(count) + " out of range");
  summary->version = static_cast<uint32_t>(version);
  summary->keyframes = static_cast<size_t>(count);
  const auto* state = static_cast<const uint8_t*>(r.blob(4));
  const size_t state_size = r.blob_size(4);
  summary->state_bytes = state_size;
  DF_RETURN_IF_ERROR(
      check_row_checksum(r, 3,
                         graph_row_checksum(summary->checkpoint_id, summary->version,
                                            static_cast<uint32_t>(count), state, state_size),
                         what));
  if (r.is_null(3)) return corrupt(what + ": the row has no checksum");
  std::vector<uint8_t> bytes;
  DF_RETURN_IF_ERROR(
      s.codec.decode_column(state, state_size, what + " state", BlobKind::kGraph, 1, &bytes));
  g->graph.version = summary->version;
  DF_RETURN_IF_ERROR(decode_state(bytes, what + " state", g));
  if (g->graph.keyframes.size() != summary->keyframes)
    return corrupt(what + ": its row counts " + std::to_string(summary->keyframes) +
                   " keyframes, its state " + std::to_string(g->graph.keyframes.size()));
  summary->loops = g->graph.loops.size();
  summary->deformation_oldest_version = g->deformation.oldest_version;
  summary->deformation_version = static_cast<uint32_t>(
      g->deformation.oldest_version + std::max<size_t>(g->deformation.T_world_kf.size(), 1) - 1);
  return Status::ok();
}

}  // namespace

Status ScanStore::write_graph(const GraphCheckpoint& g) {
  Impl& s = *impl_;
  if (!s.in_checkpoint) return invalid_argument(s.path + ": write_graph outside a checkpoint");
  const std::string ctx = "writing the pose graph";
  const std::vector<GraphKeyframe>& keyframes = g.graph.keyframes;
  // Keyframes are appended: those stored are the graph's first ones, unless the graph was
  // replaced.
  auto stored = s.stored_graph_keyframes(keyframes);
  if (!stored) return stored.status();
  size_t first = *stored;
  if (first == Impl::kReplaced) {
    DF_RETURN_IF_ERROR(s.db.exec("DELETE FROM graph_keyframes;", ctx));
    first = 0;
  }
  if (first < keyframes.size()) {
    auto ins = s.db.prepare(
        "INSERT INTO graph_keyframes (keyframe, frame_id, utime, checksum, odometry, "
        "cloud) VALUES (?, ?, ?, ?, ?, ?);",
        ctx);
    if (!ins) return ins.status();
    std::vector<uint8_t> cloud;
    for (size_t k = first; k < keyframes.size(); ++k) {
      const GraphKeyframe& kf = keyframes[k];
      if (!kf.cloud)
        return invalid_argument(s.path + ": keyframe " + std::to_string(k) +
                                " of the graph has no cloud");
      DF_RETURN_IF_ERROR(encode_cloud(s.codec, *kf.cloud, &cloud).with_context(ctx));
      Bytes odometry;
      if (k > 0) {
        odometry.pose(g.graph.odometry[k - 1].T_from_to);
        odometry.matrix(g.graph.odometry_covariance[k - 1]);
      }
      const std::vector<uint8_t>& odo = odometry.bytes();
      ins->bind(1, static_cast<int64_t>(k)).bind(2, kf.frame_id).bind(3, kf.utime);
      ins->bind(4, graph_keyframe_checksum(static_cast<uint32_t>(k), kf.frame_id, kf.utime,
                                           odo.data(), odo.size(), cloud.data(), cloud.size()));
      if (odo.empty())
        ins->bind_null(5);
      else
        ins->bind_blob(5, odo);
      ins->bind_blob(6, cloud);
      DF_RETURN_IF_ERROR(ins->run("writing keyframe " + std::to_string(k) + " of the pose graph"));
    }
  }
  std::vector<uint8_t> state;
  const std::vector<uint8_t> raw = encode_state(g);
  DF_RETURN_IF_ERROR(s.codec.encode_column(BlobKind::kGraph, raw.data(),
                                           static_cast<uint32_t>(raw.size()), 1, &state));
  const auto count = static_cast<uint32_t>(keyframes.size());
  auto row = s.db.prepare(
      "INSERT OR REPLACE INTO graph (id, checkpoint_id, version, keyframe_count, "
      "checksum, state) VALUES (1, ?, ?, ?, ?, ?);",
      ctx);
  if (!row) return row.status();
  row->bind(1, s.checkpoint_id).bind(2, g.graph.version).bind(3, count);
  row->bind(
      4, graph_row_checksum(s.checkpoint_id, g.graph.version, count, state.data(), state.size()));
  row->bind_blob(5, state);
  return row->run();
}

Result<size_t> ScanStore::Impl::stored_graph_keyframes(const std::vector<GraphKeyframe>& keyframes) {
  const std::string ctx = "reading the pose graph's keyframes";
  auto stored = db.query_int("SELECT COUNT(*) FROM graph_keyframes;", ctx);
  if (!stored) return stored.status();
  const auto n = static_cast<size_t>(*stored);
  if (n == 0) return n;
  // The last stored keyframe's frame tells a graph that continues the stored one.
  auto last = db.query_int(
      "SELECT frame_id FROM graph_keyframes WHERE keyframe = " + std::to_string(n - 1) + ";", ctx);
  if (!last) return last.status();
  if (n > keyframes.size() || keyframes[n - 1].frame_id != static_cast<uint32_t>(*last))
    return kReplaced;
  return n;
}

Status ScanStore::write_poses(const std::vector<PoseRecord>& fused,
                              const std::vector<PoseCorrection>& corrections,
                              const std::vector<GraphKeyframe>& keyframes) {
  Impl& s = *impl_;
  if (!s.in_checkpoint) return invalid_argument(s.path + ": write_poses outside a checkpoint");
  for (const PoseRecord& p : fused)
    if (p.frame_id == 0 || p.frame_id == kAllFrames)
      return invalid_argument(s.path + ": pose with frame id " + std::to_string(p.frame_id));
  // A graph that replaces the stored one numbers its keyframes anew: the rows anchored to the
  // stored one go back to the world frame first, as its keyframes have them.
  auto stored = s.stored_graph_keyframes(keyframes);
  if (!stored) return stored.status();
  if (*stored == Impl::kReplaced) DF_RETURN_IF_ERROR(s.unanchor_poses());
  // Before the first keyframe a correction moves nothing, and no keyframe anchors a pose.
  const uint32_t first = keyframes.empty() ? kAllFrames : keyframes.front().frame_id;
  auto moved = [&](uint32_t frame_id, Pose T) {
    for (const PoseCorrection& c : corrections)
      if (frame_id < c.before_frame) T = c.correction.motion_of(frame_id) * T;
    return T;
  };
  // The keyframe whose segment holds the frame: the last one made at or before it.
  auto anchor_of = [&](uint32_t frame_id) {
    const auto it = std::upper_bound(
        keyframes.begin(), keyframes.end(), frame_id,
        [](uint32_t f, const GraphKeyframe& k) { return f < k.frame_id; });
    return static_cast<uint32_t>(it - keyframes.begin()) - 1;
  };
  auto relative = [&](uint32_t frame_id, const Pose& T_world_cam) {
    const uint32_t k = anchor_of(frame_id);
    return std::make_pair(k, Pose(keyframes[k].T_world_kf.inverse() * moved(frame_id, T_world_cam)));
  };
  for (const PoseRecord& p : fused) {
    if (p.frame_id < first) {
      DF_RETURN_IF_ERROR(s.write_pose_row(p, PoseAnchor()));
      continue;
    }
    PoseRecord r = p;
    const auto [k, T_kf_cam] = relative(p.frame_id, p.T_world_cam);
    r.T_world_cam = T_kf_cam;
    DF_RETURN_IF_ERROR(s.write_pose_row(r, k));
  }
  if (keyframes.empty()) return Status::ok();
  // The rows still in the world frame (keyframes written since the last checkpoint, rows of files
  // written before schema 7 or by refine) by the partial indexes on them: read first, then
  // written, as a statement still reading the table would see the rows it rewrote. Only those of
  // the checkpoint's frames: a keyframe of a later frame (written while a background checkpoint
  // was in flight) may be in a graph version after this one, and waits for its own checkpoint. A
  // row that fails its checksum is left as it is (a new checksum would hide the damage from
  // inspect), and does not stop the checkpoint.
  const uint32_t last = s.checkpoint_up_to_frame;
  const std::vector<Pose> none;
  std::vector<PoseRecord> poses;
  {
    auto st = s.db.prepare(std::string("SELECT ") + kPoseColumns +
                               " FROM poses WHERE graph_keyframe IS NULL AND frame_id >= ? "
                               "AND frame_id <= ? ORDER BY frame_id;",
                           "reading the poses to anchor");
    if (!st) return st.status();
    st->bind(1, first).bind(2, last);
    for (const sql::Row& row : st->rows())
      if (auto p = s.pose_of(row, none)) poses.push_back(*p);
    DF_RETURN_IF_ERROR(st->status());
  }
  for (PoseRecord& p : poses) {
    const auto [k, T_kf_cam] = relative(p.frame_id, p.T_world_cam);
    p.T_world_cam = T_kf_cam;
    DF_RETURN_IF_ERROR(s.write_pose_row(p, k));
  }
  std::vector<std::pair<uint32_t, Pose>> keyframe_poses;
  {
    auto st = s.db.prepare(std::string("SELECT ") + kKeyframeColumns +
                               " FROM keyframes WHERE graph_keyframe IS NULL AND frame_id >= ? "
                               "AND frame_id <= ?;",
                           "reading the keyframe poses to anchor");
    if (!st) return st.status();
    st->bind(1, first).bind(2, last);
    Keyframe k;
    for (const sql::Row& row : st->rows())
      if (s.keyframe_head_of(row, none, &k)) keyframe_poses.emplace_back(k.frame_id, k.T_world_cam);
    DF_RETURN_IF_ERROR(st->status());
  }
  for (const auto& [id, T] : keyframe_poses) {
    const auto [k, T_kf_cam] = relative(id, T);
    DF_RETURN_IF_ERROR(s.set_keyframe_pose(id, T_kf_cam, k));
  }
  return Status::ok();
}

Status ScanStore::Impl::unanchor_poses() {
  auto anchors = graph_anchors();
  if (!anchors) return anchors.status();
  const std::vector<Pose> T_world_kf = **anchors;
  std::vector<PoseRecord> poses;
  {
    auto st = db.prepare(std::string("SELECT ") + kPoseColumns +
                             " FROM poses WHERE graph_keyframe IS NOT NULL;",
                         "reading the anchored poses");
    if (!st) return st.status();
    for (const sql::Row& row : st->rows()) {
      auto p = pose_of(row, T_world_kf);
      if (!p) return p.status();  // not stored again in a frame that would hide the damage
      poses.push_back(*p);
    }
    DF_RETURN_IF_ERROR(st->status());
  }
  for (const PoseRecord& p : poses) DF_RETURN_IF_ERROR(write_pose_row(p, PoseAnchor()));
  std::vector<std::pair<uint32_t, Pose>> keyframe_poses;
  {
    auto st = db.prepare(std::string("SELECT ") + kKeyframeColumns +
                             " FROM keyframes WHERE graph_keyframe IS NOT NULL;",
                         "reading the anchored keyframe poses");
    if (!st) return st.status();
    Keyframe k;
    for (const sql::Row& row : st->rows()) {
      DF_RETURN_IF_ERROR(keyframe_head_of(row, T_world_kf, &k));
      keyframe_poses.emplace_back(k.frame_id, k.T_world_cam);
    }
    DF_RETURN_IF_ERROR(st->status());
  }
  for (const auto& [id, T] : keyframe_poses) DF_RETURN_IF_ERROR(set_keyframe_pose(id, T, PoseAnchor()));
  return Status::ok();
}

Result<const std::vector<Pose>*> ScanStore::Impl::graph_anchors() {
  auto st = db.prepare("SELECT checkpoint_id, checksum FROM graph WHERE id = 1;",
                       "reading the pose graph's row");
  if (!st) return st.status();
  auto found = st->step();
  if (!found) return found.status();
  if (!*found) {
    anchors = Anchors{};
    return &anchors.T_world_kf;
  }
  const int64_t id = st->row().int64(0), checksum = st->row().int64(1);
  if (id == anchors.checkpoint_id && checksum == anchors.checksum) return &anchors.T_world_kf;
  GraphCheckpoint g;
  GraphSummary summary;
  bool present = false;
  DF_RETURN_IF_ERROR(read_graph_row(*this, &g, &summary, &present));
  anchors.T_world_kf.clear();
  for (const GraphKeyframe& k : g.graph.keyframes) anchors.T_world_kf.push_back(k.T_world_kf);
  anchors.checkpoint_id = id;
  anchors.checksum = checksum;
  return &anchors.T_world_kf;
}

Result<std::optional<GraphSummary>> ScanStore::graph_summary() {
  Impl& s = *impl_;
  GraphCheckpoint g;
  GraphSummary summary;
  bool found = false;
  ScopedRead snapshot(*this);
  DF_RETURN_IF_ERROR(read_graph_row(s, &g, &summary, &found));
  if (!found) return std::optional<GraphSummary>();
  auto bytes = s.db.query_int(
      "SELECT COALESCE(SUM(length(cloud)), 0) FROM graph_keyframes WHERE keyframe < " +
          std::to_string(summary.keyframes) + ";",
      "sizing the pose graph's keyframes");
  if (!bytes) return bytes.status();
  summary.keyframe_bytes = static_cast<uint64_t>(*bytes);
  return std::optional<GraphSummary>(summary);
}

Result<std::optional<GraphCheckpoint>> ScanStore::read_graph() {
  Impl& s = *impl_;
  ScopedRead snapshot(*this);
  GraphCheckpoint g;
  GraphSummary summary;
  bool found = false;
  DF_RETURN_IF_ERROR(read_graph_row(s, &g, &summary, &found));
  if (!found) return std::optional<GraphCheckpoint>();
  auto st = s.db.prepare(
      "SELECT keyframe, frame_id, utime, checksum, odometry, cloud FROM graph_keyframes "
      "WHERE keyframe < ? ORDER BY keyframe;",
      "reading the pose graph's keyframes");
  if (!st) return st.status();
  st->bind(1, static_cast<int64_t>(summary.keyframes));
  size_t k = 0;
  for (const sql::Row& row : st->rows()) {
    const std::string what = s.path + ": keyframe " + std::to_string(k) + " of the pose graph";
    if (row.int64(0) != static_cast<int64_t>(k))
      return corrupt(what + " is missing (found keyframe " + std::to_string(row.int64(0)) + ")");
    const int64_t frame_id = row.int64(1);
    if (frame_id < 1 || frame_id >= kAllFrames)
      return corrupt(what + ": the frame id is out of range");
    GraphKeyframe& kf = g.graph.keyframes[k];
    kf.frame_id = static_cast<uint32_t>(frame_id);
    kf.utime = row.int64(2);
    const void* odo = row.blob(4);
    const size_t odo_size = row.blob_size(4);
    const void* cloud = row.blob(5);
    const size_t cloud_size = row.blob_size(5);
    if (row.is_null(3)) return corrupt(what + ": the row has no checksum");
    DF_RETURN_IF_ERROR(
        check_row_checksum(row, 3,
                           graph_keyframe_checksum(static_cast<uint32_t>(k), kf.frame_id, kf.utime,
                                                   odo, odo_size, cloud, cloud_size),
                           what));
    auto c = std::make_shared<KeyframeCloud>();
    DF_RETURN_IF_ERROR(decode_cloud(s.codec, cloud, cloud_size, what + " cloud", c.get()));
    kf.cloud = std::move(c);
    if (k > 0) {
      Reader r(static_cast<const uint8_t*>(odo), odo_size, what + " odometry");
      PoseGraphEdge e;
      Matrix6d covariance;
      DF_RETURN_IF_ERROR(r.pose(&e.T_from_to));
      DF_RETURN_IF_ERROR(r.matrix(&covariance));
      DF_RETURN_IF_ERROR(r.done());
      e.from = static_cast<uint32_t>(k - 1);
      e.to = static_cast<uint32_t>(k);
      e.information = covariance.inverse();  // as ScanGraph made it
      e.kind = PoseGraphEdge::Kind::kOdometry;
      g.graph.odometry.push_back(e);
      g.graph.odometry_covariance.push_back(covariance);
    } else if (odo_size != 0) {
      return corrupt(what + ": the first keyframe has an odometry edge");
    }
    ++k;
  }
  DF_RETURN_IF_ERROR(st->status());
  if (k != summary.keyframes)
    return corrupt(s.path + ": the pose graph counts " + std::to_string(summary.keyframes) +
                   " keyframes, the file holds " + std::to_string(k));
  // The map follows the graph's keyframes: each one's segment starts at its frame.
  const std::vector<uint32_t>& first = g.deformation.keyframe_first_frame;
  if (first.size() != k)
    return corrupt(s.path + ": the pose graph has " + std::to_string(k) +
                   " keyframes, the map's deformation " + std::to_string(first.size()));
  for (size_t i = 0; i < k; ++i)
    if (first[i] != g.graph.keyframes[i].frame_id)
      return corrupt(s.path + ": keyframe " + std::to_string(i) + " of the pose graph is frame " +
                     std::to_string(g.graph.keyframes[i].frame_id) +
                     ", the map's deformation starts its segment at frame " +
                     std::to_string(first[i]));
  return std::optional<GraphCheckpoint>(std::move(g));
}

}  // namespace depthfuse::store
