#include "depthfuse/store/scan_store.hpp"

#include <fcntl.h>
#include <sys/file.h>
#include <sys/stat.h>
#include <unistd.h>

#include <cerrno>
#include <chrono>
#include <cmath>
#include <cstring>
#include <limits>

#include "depthfuse/store/blob_codec.hpp"
#include "schema.hpp"
#include "sqlite_db.hpp"

namespace depthfuse::store {

namespace {

int64_t now_utime() {
  return std::chrono::duration_cast<std::chrono::microseconds>(
             std::chrono::system_clock::now().time_since_epoch())
      .count();
}

std::string errno_text() { return std::strerror(errno); }

uint64_t file_size(const std::string& path) {
  struct stat st {};
  return ::stat(path.c_str(), &st) == 0 ? static_cast<uint64_t>(st.st_size) : 0;
}

bool file_exists(const std::string& path) {
  struct stat st {};
  return ::stat(path.c_str(), &st) == 0;
}

// Checks that `path` looks like an SQLite file before SQLite sees it, so that an empty, foreign or
// truncated file gets an error naming the problem.
Status check_file_header(const std::string& path) {
  struct stat st {};
  if (::stat(path.c_str(), &st) != 0) {
    if (errno == ENOENT) return not_found(path + ": no such scan file");
    return io_error(path + ": " + errno_text());
  }
  if (S_ISDIR(st.st_mode)) return invalid_argument(path + ": is a directory, not a scan file");
  const int fd = ::open(path.c_str(), O_RDONLY | O_CLOEXEC);
  if (fd < 0) return io_error(path + ": cannot open: " + errno_text());
  unsigned char h[100];
  const ssize_t n = ::pread(fd, h, sizeof(h), 0);
  ::close(fd);
  if (n < 0) return io_error(path + ": cannot read: " + errno_text());
  if (n == 0) return corrupt(path + ": the file is empty, not a scan file");
  if (n < static_cast<ssize_t>(sizeof(h)) || std::memcmp(h, "SQLite format 3", 16) != 0)
    return corrupt(path + ": not a scan file (no SQLite header; the file is damaged or of "
                          "another kind)");
  // Page size (big endian; 1 means 65536) and the in-header database size, which is valid when
  // the change counter matches "version valid for". Without a WAL beside it, a file shorter than
  // that was truncated.
  uint32_t page_size = (static_cast<uint32_t>(h[16]) << 8) | h[17];
  if (page_size == 1) page_size = 65536;
  auto be32 = [&](int o) {
    return (static_cast<uint32_t>(h[o]) << 24) | (static_cast<uint32_t>(h[o + 1]) << 16) |
           (static_cast<uint32_t>(h[o + 2]) << 8) | h[o + 3];
  };
  const uint32_t pages = be32(28);
  if (be32(24) == be32(92) && pages > 0 && !file_exists(path + "-wal")) {
    const uint64_t expected = static_cast<uint64_t>(pages) * page_size;
    if (static_cast<uint64_t>(st.st_size) < expected)
      return corrupt(path + ": the file is truncated (" + std::to_string(st.st_size) +
                     " bytes, its header says " + std::to_string(expected) + ")");
  }
  return Status::ok();
}

void put_meta_text(std::vector<std::pair<std::string, std::string>>* kv, const char* key,
                   const std::string& v) {
  kv->emplace_back(key, v);
}

std::string format_double(double v) {
  char buf[64];
  std::snprintf(buf, sizeof(buf), "%.17g", v);
  return buf;
}

Eigen::AlignedBox3f bounds_of(const PointArrays& a) {
  Eigen::AlignedBox3f box;
  for (size_t i = 0; i < a.size(); ++i) box.extend(a.position_m[i]);
  return box;
}

}  // namespace

std::string to_string(const ChunkKey& k) {
  return "(" + std::to_string(k.x) + "," + std::to_string(k.y) + "," + std::to_string(k.z) + ")";
}

Keyframe Keyframe::from_frame(const Frame& frame, uint32_t frame_id, const Pose& T_world_cam,
                              bool keep_color) {
  Keyframe k;
  k.frame_id = frame_id;
  k.utime = frame.utime;
  k.sensor_serial = frame.sensor_serial;
  k.intrinsics = frame.intrinsics;
  k.T_world_cam = T_world_cam;
  k.depth = frame.depth;
  if (keep_color) k.color = frame.color;
  return k;
}

Frame Keyframe::to_frame() const {
  Frame f;
  f.utime = utime;
  f.sequence = frame_id;
  f.sensor_serial = sensor_serial;
  f.intrinsics = intrinsics;
  f.depth = depth;
  f.color = color;
  f.T_world_cam_hint = T_world_cam;
  return f;
}

struct ScanStore::Impl {
  std::string path;
  OpenMode mode = OpenMode::kReadOnly;
  StoreOptions options;
  sql::Database db;
  int lock_fd = -1;
  int schema_version = 0;
  OpenReport report;
  BlobCodec codec;
  bool in_checkpoint = false;
  int64_t checkpoint_id = 0;       // of the open checkpoint
  int read_depth = 0;
  std::vector<uint8_t> blob;

  explicit Impl(int level) : codec(level) {}
  ~Impl() {
    if (in_checkpoint) (void)db.exec("ROLLBACK;", "rolling back");
    db.close();
    // After SQLite closed its descriptors: closing ours earlier would drop SQLite's POSIX locks.
    if (lock_fd >= 0) ::close(lock_fd);
  }

  bool writable() const { return mode != OpenMode::kReadOnly; }

  Status require_writable(const char* what) const {
    if (!writable()) return invalid_argument(path + ": " + what + ": the scan is open read-only");
    return Status::ok();
  }

  // Runs fn inside the open checkpoint, or else in a transaction of its own.
  template <typename Fn>
  Status in_transaction(const std::string& ctx, Fn&& fn) {
    if (in_checkpoint) {
      Status st = fn();
      return st;
    }
    DF_RETURN_IF_ERROR(db.exec("BEGIN IMMEDIATE;", ctx));
    Status st = fn();
    if (st) st = db.exec("COMMIT;", ctx);
    if (!st && !sqlite3_get_autocommit(db.handle())) (void)db.exec("ROLLBACK;", ctx);
    return st;
  }

  Status set_meta(const std::vector<std::pair<std::string, std::string>>& kv) {
    auto st = db.prepare("INSERT OR REPLACE INTO meta (key, value) VALUES (?, ?);", "writing meta");
    if (!st) return st.status();
    for (const auto& [k, v] : kv) {
      st->bind(1, k).bind(2, v);
      DF_RETURN_IF_ERROR(st->run("writing meta '" + k + "'"));
    }
    return Status::ok();
  }

  Result<std::optional<std::string>> get_meta(const std::string& key) {
    auto st = db.prepare("SELECT value FROM meta WHERE key = ?;", "reading meta");
    if (!st) return st.status();
    st->bind(1, key);
    auto row = st->step("reading meta '" + key + "'");
    if (!row) return row.status();
    if (!*row) return std::optional<std::string>();
    return std::optional<std::string>(st->text(0));
  }

  Result<int64_t> last_checkpoint_frame() {
    return db.query_int("SELECT COALESCE((SELECT last_frame_id FROM checkpoints ORDER BY id DESC "
                        "LIMIT 1), 0);",
                        "reading the last checkpoint");
  }

  Status write_chunk_row(const char* table, const ChunkKey& key, const Chunk& chunk,
                         int64_t last_column) {
    DF_RETURN_IF_ERROR(codec.encode_points(chunk.points, &blob).with_context(
        path + ": encoding chunk " + to_string(key)));
    const Eigen::AlignedBox3f box = bounds_of(chunk.points);
    const std::string sql =
        std::string("INSERT OR REPLACE INTO ") + table +
        " (x, y, z, point_count, min_x, min_y, min_z, max_x, max_y, max_z, last_touched_frame, " +
        (std::strcmp(table, "chunks") == 0 ? "checkpoint_id" : "staged_utime") +
        ", data) VALUES (?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?);";
    const std::string ctx = std::string("writing chunk ") + to_string(key);
    auto st = db.prepare(sql, ctx);
    if (!st) return st.status();
    st->bind(1, key.x).bind(2, key.y).bind(3, key.z);
    st->bind(4, static_cast<int64_t>(chunk.points.size()));
    if (box.isEmpty()) {
      for (int i = 5; i <= 10; ++i) st->bind_null(i);
    } else {
      for (int i = 0; i < 3; ++i) {
        st->bind(5 + i, static_cast<double>(box.min()[i]));
        st->bind(8 + i, static_cast<double>(box.max()[i]));
      }
    }
    st->bind(11, chunk.last_touched_frame);
    st->bind(12, last_column);
    st->bind_blob(13, blob);
    return st->run(ctx);
  }

  Status delete_key(const char* table, const ChunkKey& key) {
    const std::string ctx = std::string("deleting chunk ") + to_string(key);
    auto st = db.prepare(std::string("DELETE FROM ") + table + " WHERE x = ? AND y = ? AND z = ?;",
                         ctx);
    if (!st) return st.status();
    st->bind(1, key.x).bind(2, key.y).bind(3, key.z);
    return st->run(ctx);
  }

  // Reads one chunk row (columns in kChunkColumns order) into `out`.
  Status decode_chunk_row(const sql::Statement& st, bool staged, StoredChunk* out) {
    ChunkInfo& info = out->info;
    info.key = {static_cast<int32_t>(st.int64(0)), static_cast<int32_t>(st.int64(1)),
                static_cast<int32_t>(st.int64(2))};
    info.point_count = static_cast<uint32_t>(st.int64(3));
    info.bounds_m.setEmpty();
    if (!st.is_null(4)) {
      info.bounds_m.min() = Eigen::Vector3f(st.real(4), st.real(5), st.real(6));
      info.bounds_m.max() = Eigen::Vector3f(st.real(7), st.real(8), st.real(9));
    }
    info.last_touched_frame = static_cast<uint32_t>(st.int64(10));
    info.checkpoint_id = staged ? 0 : st.int64(11);
    info.blob_bytes = st.blob_size(12);
    const std::string what = path + ": " + (staged ? "staged chunk " : "chunk ") +
                             to_string(info.key);
    DF_RETURN_IF_ERROR(codec.decode_points(st.blob(12), st.blob_size(12), what,
                                           &out->chunk.points));
    if (out->chunk.points.size() != info.point_count)
      return corrupt(what + ": holds " + std::to_string(out->chunk.points.size()) +
                     " points, its row says " + std::to_string(info.point_count));
    out->chunk.last_touched_frame = info.last_touched_frame;
    out->chunk.dirty = false;
    return Status::ok();
  }

  Result<CheckpointRecord> read_checkpoint_row(const sql::Statement& st) {
    CheckpointRecord r;
    r.id = st.int64(0);
    r.utime = st.int64(1);
    r.reason = st.text(2);
    r.last_frame_id = static_cast<uint32_t>(st.int64(3));
    r.frames_fused = static_cast<uint64_t>(st.int64(4));
    r.point_count = static_cast<uint64_t>(st.int64(5));
    r.chunk_count = static_cast<uint64_t>(st.int64(6));
    if (!st.is_null(7)) {
      Pose T;
      DF_RETURN_IF_ERROR(decode_pose(st.blob(7), st.blob_size(7),
                                     path + ": checkpoint " + std::to_string(r.id), &T));
      r.T_world_cam = T;
    }
    return r;
  }

  Status enable_wal() {
    auto mode = db.prepare("PRAGMA journal_mode = WAL;", "enabling WAL");
    if (!mode) return mode.status();
    auto row = mode->step("enabling WAL");
    if (!row) return row.status();
    if (!*row || mode->text(0) != "wal")
      return io_error(path + ": the file system does not support WAL mode");
    return Status::ok();
  }
  Status open_existing();
  Status create_new();
  Status recover();
};

namespace {
constexpr const char* kChunkColumns =
    "x, y, z, point_count, min_x, min_y, min_z, max_x, max_y, max_z, last_touched_frame";
constexpr const char* kCheckpointColumns =
    "id, utime, reason, last_frame_id, frames_fused, point_count, chunk_count, T_world_cam";
}  // namespace

// A new scan appears under its name only complete: the schema is built in a temporary file
// beside it, which is then linked into place (link fails if the name exists, so two creators
// cannot both win). A crash during creation leaves no half-made scan file behind the name.
Status ScanStore::Impl::create_new() {
  if (file_exists(path)) return invalid_argument(path + ": already exists; a new scan needs a new file");
  const std::string tmp = path + ".creating-" + std::to_string(::getpid());
  auto cleanup = [&] {
    ::unlink(tmp.c_str());
    ::unlink((tmp + "-journal").c_str());
    ::unlink((tmp + "-wal").c_str());
    ::unlink((tmp + "-shm").c_str());
  };
  cleanup();
  Status st;
  {
    sql::Database fresh;
    st = fresh.open(tmp, SQLITE_OPEN_READWRITE | SQLITE_OPEN_CREATE | SQLITE_OPEN_NOMUTEX);
    if (st) st = fresh.exec("PRAGMA synchronous = FULL;", "setting synchronous");
    // Pages freed by deleted chunks can be returned to the file system (ScanStore::compact).
    if (st) st = fresh.exec("PRAGMA auto_vacuum = INCREMENTAL;", "setting auto_vacuum");
    if (st) st = fresh.exec("BEGIN IMMEDIATE;", "creating the scan");
    if (st) st = schema::create_current(fresh);
    if (st) {
      auto meta = fresh.prepare("INSERT INTO meta (key, value) VALUES ('created_utime', ?), "
                                "('chunk_size_m', '0.5');",
                                "creating the scan");
      if (!meta) st = meta.status();
      else st = meta->bind(1, std::to_string(now_utime())).run("creating the scan");
    }
    if (st) st = fresh.exec("COMMIT;", "creating the scan");
    // WAL (persistent in the file): readers never block the writer, and a crash in the middle
    // of a transaction leaves the last commit.
    if (st) {
      auto mode = fresh.prepare("PRAGMA journal_mode = WAL;", "enabling WAL");
      if (!mode) st = mode.status();
      else if (auto row = mode->step("enabling WAL"); !row) st = row.status();
      else if (!*row || mode->text(0) != "wal")
        st = io_error(path + ": the file system does not support WAL mode");
    }
  }
  if (st && ::link(tmp.c_str(), path.c_str()) != 0) {
    st = errno == EEXIST ? invalid_argument(path + ": already exists; a new scan needs a new file")
                         : io_error(path + ": cannot create: " + errno_text());
  }
  cleanup();
  if (!st) return st.with_context("creating " + path);
  // The new name must survive a power cut too.
  const std::string dir = path.find('/') == std::string::npos ? "." : path.substr(0, path.rfind('/') + 1);
  if (const int dfd = ::open(dir.c_str(), O_RDONLY | O_DIRECTORY | O_CLOEXEC); dfd >= 0) {
    (void)::fsync(dfd);
    ::close(dfd);
  }
  DF_RETURN_IF_ERROR(open_existing());
  report.found_schema_version = 0;
  return Status::ok();
}

Status ScanStore::Impl::open_existing() {
  DF_RETURN_IF_ERROR(check_file_header(path));
  if (writable()) {
    lock_fd = ::open(path.c_str(), O_RDWR | O_CLOEXEC);
    if (lock_fd < 0) return io_error(path + ": cannot open for writing: " + errno_text());
    if (::flock(lock_fd, LOCK_EX | LOCK_NB) != 0) {
      if (errno == EWOULDBLOCK)
        return unavailable(path + ": another process is writing this scan (the fusion daemon?); "
                                  "open it read-only or stop the writer");
      return io_error(path + ": cannot lock: " + errno_text());
    }
  }
  const int flags = (writable() ? SQLITE_OPEN_READWRITE : SQLITE_OPEN_READONLY) | SQLITE_OPEN_NOMUTEX;
  DF_RETURN_IF_ERROR(db.open(path, flags));
  sqlite3_busy_timeout(db.handle(), options.busy_timeout_ms);
  // The first read of the schema is where SQLite finds a foreign or damaged file.
  auto tables = db.query_int("SELECT COUNT(*) FROM sqlite_schema;", "reading the schema");
  if (!tables) return tables.status();
  auto app = db.query_int("PRAGMA application_id;", "reading the file's application id");
  if (!app) return app.status();
  auto version = db.query_int("PRAGMA user_version;", "reading the schema version");
  if (!version) return version.status();
  if (*app != kApplicationId) {
    char buf[32];
    std::snprintf(buf, sizeof(buf), "0x%08x", static_cast<unsigned>(*app));
    return invalid_argument(path + ": an SQLite database but not a depthfuse scan (application_id " +
                            buf + ")");
  }
  report.found_schema_version = static_cast<int>(*version);
  if (*version > kSchemaVersion)
    return unsupported(path + ": schema version " + std::to_string(*version) +
                       " was written by a newer depthfuse (this one reads up to " +
                       std::to_string(kSchemaVersion) + ")");
  if (*version < 1) return corrupt(path + ": schema version " + std::to_string(*version) + " is invalid");
  if (*version < kSchemaVersion) {
    if (!writable())
      return unsupported(path + ": schema version " + std::to_string(*version) +
                         " is older than this depthfuse's " + std::to_string(kSchemaVersion) +
                         "; open it read-write once to migrate (depthfuse inspect --upgrade)");
    DF_RETURN_IF_ERROR(db.exec("PRAGMA synchronous = FULL;", "setting synchronous"));
    DF_RETURN_IF_ERROR(db.exec("BEGIN IMMEDIATE;", "migrating"));
    Status st = schema::migrate(db, static_cast<int>(*version));
    if (st) st = db.exec("COMMIT;", "migrating");
    if (!st) {
      if (!sqlite3_get_autocommit(db.handle())) (void)db.exec("ROLLBACK;", "migrating");
      return st.with_context("migrating from schema " + std::to_string(*version));
    }
    report.migrated = true;
  }
  schema_version = kSchemaVersion;
  for (const char* const* t = schema::kTables; *t; ++t) {
    auto n = db.query_int(std::string("SELECT COUNT(*) FROM sqlite_schema WHERE type = 'table' AND "
                                      "name = '") + *t + "';",
                          "checking the schema");
    if (!n) return n.status();
    if (*n != 1) return corrupt(path + ": table '" + *t + "' is missing");
  }
  if (writable()) {
    DF_RETURN_IF_ERROR(enable_wal());
    DF_RETURN_IF_ERROR(recover());
    DF_RETURN_IF_ERROR(db.exec("PRAGMA synchronous = NORMAL;", "setting synchronous"));
  }
  return Status::ok();
}

// A writer reopening the file drops what was written after the last checkpoint: staged chunks,
// and poses and keyframes of later frames. The file is then exactly the last checkpoint.
Status ScanStore::Impl::recover() {
  DF_RETURN_IF_ERROR(db.exec("PRAGMA synchronous = FULL;", "setting synchronous"));
  return in_transaction("discarding work after the last checkpoint", [&]() -> Status {
    auto last = last_checkpoint_frame();
    if (!last) return last.status();
    DF_RETURN_IF_ERROR(db.exec("DELETE FROM chunk_staging;", "discarding staged chunks"));
    report.discarded_staged_chunks = static_cast<size_t>(sqlite3_changes(db.handle()));
    DF_RETURN_IF_ERROR(db.exec("DELETE FROM poses WHERE frame_id > " + std::to_string(*last) + ";",
                               "discarding poses"));
    report.discarded_poses = static_cast<size_t>(sqlite3_changes(db.handle()));
    DF_RETURN_IF_ERROR(db.exec("DELETE FROM keyframes WHERE frame_id > " + std::to_string(*last) +
                                   ";",
                               "discarding keyframes"));
    report.discarded_keyframes = static_cast<size_t>(sqlite3_changes(db.handle()));
    return Status::ok();
  });
}

Result<std::unique_ptr<ScanStore>> ScanStore::open(const std::string& path, OpenMode mode,
                                                   const StoreOptions& options) {
  auto impl = std::make_unique<Impl>(options.compression_level);
  impl->path = path;
  impl->mode = mode;
  impl->options = options;
  if (mode == OpenMode::kCreate) {
    DF_RETURN_IF_ERROR(impl->create_new());
  } else {
    DF_RETURN_IF_ERROR(impl->open_existing());
  }
  return std::unique_ptr<ScanStore>(new ScanStore(std::move(impl)));
}

ScanStore::ScanStore(std::unique_ptr<Impl> impl) : impl_(std::move(impl)) {}
ScanStore::~ScanStore() = default;

const std::string& ScanStore::path() const { return impl_->path; }
bool ScanStore::read_only() const { return !impl_->writable(); }
int ScanStore::schema_version() const { return impl_->schema_version; }
const OpenReport& ScanStore::open_report() const { return impl_->report; }

Status ScanStore::set_metadata(const ScanMetadata& m) {
  DF_RETURN_IF_ERROR(impl_->require_writable("set_metadata"));
  std::vector<std::pair<std::string, std::string>> kv;
  put_meta_text(&kv, "scan_id", m.scan_id);
  put_meta_text(&kv, "created_utime", std::to_string(m.created_utime));
  put_meta_text(&kv, "sensor_serial", m.sensor_serial);
  put_meta_text(&kv, "method", m.method);
  put_meta_text(&kv, "chunk_size_m", format_double(m.chunk_size_m));
  put_meta_text(&kv, "software_version", m.software_version);
  put_meta_text(&kv, "frames_received", std::to_string(m.frames_received));
  put_meta_text(&kv, "frames_fused", std::to_string(m.frames_fused));
  put_meta_text(&kv, "frames_dropped", std::to_string(m.frames_dropped));
  return impl_->in_transaction("writing metadata", [&] { return impl_->set_meta(kv); });
}

Result<ScanMetadata> ScanStore::metadata() {
  auto st = impl_->db.prepare("SELECT key, value FROM meta;", "reading metadata");
  if (!st) return st.status();
  ScanMetadata m;
  for (;;) {
    auto row = st->step("reading metadata");
    if (!row) return row.status();
    if (!*row) break;
    const std::string k = st->text(0), v = st->text(1);
    auto as_u64 = [&](uint64_t* out) { *out = std::strtoull(v.c_str(), nullptr, 10); };
    if (k == "scan_id") m.scan_id = v;
    else if (k == "created_utime") m.created_utime = std::strtoll(v.c_str(), nullptr, 10);
    else if (k == "sensor_serial") m.sensor_serial = v;
    else if (k == "method") m.method = v;
    else if (k == "chunk_size_m") {
      m.chunk_size_m = std::strtod(v.c_str(), nullptr);
      if (!(m.chunk_size_m > 0.0) || !std::isfinite(m.chunk_size_m))
        return corrupt(impl_->path + ": meta chunk_size_m '" + v + "' is not a positive number");
    } else if (k == "software_version") m.software_version = v;
    else if (k == "frames_received") as_u64(&m.frames_received);
    else if (k == "frames_fused") as_u64(&m.frames_fused);
    else if (k == "frames_dropped") as_u64(&m.frames_dropped);
  }
  return m;
}

Status ScanStore::set_config(const std::string& toml_text, const std::string& source_path) {
  DF_RETURN_IF_ERROR(impl_->require_writable("set_config"));
  return impl_->in_transaction("writing the configuration", [&] {
    return impl_->set_meta({{"config_toml", toml_text}, {"config_source", source_path}});
  });
}

Result<std::optional<std::string>> ScanStore::config_toml() { return impl_->get_meta("config_toml"); }

Status ScanStore::begin_checkpoint() {
  DF_RETURN_IF_ERROR(impl_->require_writable("begin_checkpoint"));
  if (impl_->in_checkpoint) return invalid_argument(impl_->path + ": a checkpoint is already open");
  if (impl_->read_depth > 0) return invalid_argument(impl_->path + ": a read snapshot is open");
  // FULL: the commit record is fsynced before COMMIT returns, so a checkpoint that was reported
  // written survives a power cut.
  DF_RETURN_IF_ERROR(impl_->db.exec("PRAGMA synchronous = FULL;", "setting synchronous"));
  DF_RETURN_IF_ERROR(impl_->db.exec("BEGIN IMMEDIATE;", "beginning a checkpoint"));
  auto id = impl_->db.query_int("SELECT COALESCE(MAX(id), 0) + 1 FROM checkpoints;",
                                "numbering the checkpoint");
  if (!id) {
    (void)impl_->db.exec("ROLLBACK;", "rolling back");
    return id.status();
  }
  impl_->checkpoint_id = *id;
  impl_->in_checkpoint = true;
  return Status::ok();
}

bool ScanStore::in_checkpoint() const { return impl_->in_checkpoint; }

void ScanStore::rollback_checkpoint() {
  if (!impl_->in_checkpoint) return;
  impl_->in_checkpoint = false;
  if (!sqlite3_get_autocommit(impl_->db.handle())) (void)impl_->db.exec("ROLLBACK;", "rolling back");
  (void)impl_->db.exec("PRAGMA synchronous = NORMAL;", "setting synchronous");
}

Status ScanStore::write_chunk(const ChunkKey& key, const Chunk& chunk) {
  if (!impl_->in_checkpoint) return invalid_argument(impl_->path + ": write_chunk outside a checkpoint");
  DF_RETURN_IF_ERROR(impl_->delete_key("chunk_staging", key));
  if (chunk.points.empty()) return impl_->delete_key("chunks", key);
  return impl_->write_chunk_row("chunks", key, chunk, impl_->checkpoint_id);
}

Status ScanStore::delete_chunk(const ChunkKey& key) {
  if (!impl_->in_checkpoint) return invalid_argument(impl_->path + ": delete_chunk outside a checkpoint");
  DF_RETURN_IF_ERROR(impl_->delete_key("chunk_staging", key));
  return impl_->delete_key("chunks", key);
}

Status ScanStore::delete_all_chunks() {
  if (!impl_->in_checkpoint)
    return invalid_argument(impl_->path + ": delete_all_chunks outside a checkpoint");
  DF_RETURN_IF_ERROR(impl_->db.exec("DELETE FROM chunk_staging;", "deleting chunks"));
  return impl_->db.exec("DELETE FROM chunks;", "deleting chunks");
}

Status ScanStore::write_pose(const PoseRecord& p) {
  DF_RETURN_IF_ERROR(impl_->require_writable("write_pose"));
  return impl_->in_transaction("writing poses", [&]() -> Status {
    const std::string ctx = "writing the pose of frame " + std::to_string(p.frame_id);
    auto st = impl_->db.prepare(
        "INSERT OR REPLACE INTO poses (frame_id, utime, T_world_cam, registered, fitness, rmse_m, "
        "correspondences) VALUES (?, ?, ?, ?, ?, ?, ?);",
        ctx);
    if (!st) return st.status();
    const std::vector<uint8_t> pose = encode_pose(p.T_world_cam);
    st->bind(1, p.frame_id).bind(2, p.utime).bind_blob(3, pose).bind(4, p.registered ? 1 : 0);
    st->bind(5, p.fitness).bind(6, p.rmse_m).bind(7, p.correspondences);
    return st->run(ctx);
  });
}

Status ScanStore::update_keyframe_pose(uint32_t frame_id, const Pose& T_world_cam) {
  DF_RETURN_IF_ERROR(impl_->require_writable("update_keyframe_pose"));
  return impl_->in_transaction("updating a keyframe pose", [&]() -> Status {
    const std::string ctx = "updating the pose of keyframe " + std::to_string(frame_id);
    auto st = impl_->db.prepare("UPDATE keyframes SET T_world_cam = ? WHERE frame_id = ?;", ctx);
    if (!st) return st.status();
    const std::vector<uint8_t> pose = encode_pose(T_world_cam);
    st->bind_blob(1, pose).bind(2, frame_id);
    DF_RETURN_IF_ERROR(st->run(ctx));
    if (sqlite3_changes(impl_->db.handle()) != 1)
      return not_found(impl_->path + ": no keyframe " + std::to_string(frame_id));
    return Status::ok();
  });
}

Status ScanStore::write_keyframe(const Keyframe& k) {
  DF_RETURN_IF_ERROR(impl_->require_writable("write_keyframe"));
  const std::string ctx = "writing keyframe " + std::to_string(k.frame_id);
  if (!k.intrinsics.valid() || k.depth.width != k.intrinsics.width ||
      k.depth.height != k.intrinsics.height)
    return invalid_argument(impl_->path + ": " + ctx + ": depth size does not match its intrinsics");
  std::vector<uint8_t> depth, color;
  DF_RETURN_IF_ERROR(impl_->codec.encode_depth(k.depth, &depth).with_context(ctx));
  if (!k.color.empty()) DF_RETURN_IF_ERROR(impl_->codec.encode_color(k.color, &color).with_context(ctx));
  const std::vector<uint8_t> pose = encode_pose(k.T_world_cam);
  return impl_->in_transaction(ctx, [&]() -> Status {
    auto st = impl_->db.prepare(
        "INSERT OR REPLACE INTO keyframes (frame_id, utime, sensor_serial, width, height, fx, fy, "
        "cx, cy, T_world_cam, depth, color) VALUES (?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?);",
        ctx);
    if (!st) return st.status();
    st->bind(1, k.frame_id).bind(2, k.utime).bind(3, k.sensor_serial);
    st->bind(4, k.intrinsics.width).bind(5, k.intrinsics.height);
    st->bind(6, k.intrinsics.fx).bind(7, k.intrinsics.fy);
    st->bind(8, k.intrinsics.cx).bind(9, k.intrinsics.cy);
    st->bind_blob(10, pose).bind_blob(11, depth);
    if (color.empty()) st->bind_null(12); else st->bind_blob(12, color);
    return st->run(ctx);
  });
}

Result<CheckpointRecord> ScanStore::commit_checkpoint(const CheckpointInfo& info) {
  Impl& s = *impl_;
  if (!s.in_checkpoint) return invalid_argument(s.path + ": commit_checkpoint without a checkpoint");
  const std::string ctx = "committing checkpoint " + std::to_string(s.checkpoint_id);
  CheckpointRecord rec;
  rec.id = s.checkpoint_id;
  rec.utime = now_utime();
  rec.reason = info.reason;
  rec.last_frame_id = info.last_frame_id;
  rec.frames_fused = info.frames_fused;
  rec.T_world_cam = info.T_world_cam;
  auto body = [&]() -> Status {
    // Staged chunks (evicted since the last checkpoint) become part of this one; staged empty
    // chunks are deletions.
    DF_RETURN_IF_ERROR(s.db.exec(
        "DELETE FROM chunks WHERE EXISTS (SELECT 1 FROM chunk_staging AS s WHERE s.x = chunks.x "
        "AND s.y = chunks.y AND s.z = chunks.z AND s.point_count = 0);",
        ctx));
    DF_RETURN_IF_ERROR(s.db.exec(
        std::string("INSERT OR REPLACE INTO chunks (") + kChunkColumns +
            ", checkpoint_id, data) SELECT " + kChunkColumns + ", " +
            std::to_string(s.checkpoint_id) + ", data FROM chunk_staging WHERE point_count > 0;",
        ctx));
    DF_RETURN_IF_ERROR(s.db.exec("DELETE FROM chunk_staging;", ctx));
    auto counts = s.db.prepare("SELECT COUNT(*), COALESCE(SUM(point_count), 0) FROM chunks;", ctx);
    if (!counts) return counts.status();
    auto row = counts->step(ctx);
    if (!row) return row.status();
    rec.chunk_count = static_cast<uint64_t>(counts->int64(0));
    rec.point_count = static_cast<uint64_t>(counts->int64(1));
    auto ins = s.db.prepare(std::string("INSERT INTO checkpoints (") + kCheckpointColumns +
                                ") VALUES (?, ?, ?, ?, ?, ?, ?, ?);",
                            ctx);
    if (!ins) return ins.status();
    std::vector<uint8_t> pose;
    if (info.T_world_cam) pose = encode_pose(*info.T_world_cam);
    ins->bind(1, rec.id).bind(2, rec.utime).bind(3, rec.reason).bind(4, rec.last_frame_id);
    ins->bind(5, static_cast<int64_t>(rec.frames_fused)).bind(6, static_cast<int64_t>(rec.point_count));
    ins->bind(7, static_cast<int64_t>(rec.chunk_count));
    if (pose.empty()) ins->bind_null(8); else ins->bind_blob(8, pose);
    DF_RETURN_IF_ERROR(ins->run(ctx));
    DF_RETURN_IF_ERROR(s.set_meta({{"frames_received", std::to_string(info.frames_received)},
                                   {"frames_fused", std::to_string(info.frames_fused)},
                                   {"frames_dropped", std::to_string(info.frames_dropped)}}));
    return s.db.exec("COMMIT;", ctx);
  };
  Status st = body();
  s.in_checkpoint = false;
  if (!st) {
    if (!sqlite3_get_autocommit(s.db.handle())) (void)s.db.exec("ROLLBACK;", "rolling back");
    (void)s.db.exec("PRAGMA synchronous = NORMAL;", "setting synchronous");
    return st;
  }
  (void)s.db.exec("PRAGMA synchronous = NORMAL;", "setting synchronous");
  return rec;
}

Status ScanStore::stage_chunks(const std::vector<std::pair<ChunkKey, const Chunk*>>& chunks) {
  Impl& s = *impl_;
  DF_RETURN_IF_ERROR(s.require_writable("stage_chunks"));
  if (s.in_checkpoint)
    return invalid_argument(s.path + ": cannot stage chunks while a checkpoint is open");
  if (chunks.empty()) return Status::ok();
  const int64_t t = now_utime();
  return s.in_transaction("staging evicted chunks", [&]() -> Status {
    for (const auto& [key, chunk] : chunks) DF_RETURN_IF_ERROR(s.write_chunk_row("chunk_staging", key, *chunk, t));
    return Status::ok();
  });
}

Status ScanStore::begin_read() {
  Impl& s = *impl_;
  if (s.in_checkpoint) return invalid_argument(s.path + ": begin_read inside a checkpoint");
  if (s.read_depth++ > 0) return Status::ok();
  Status st = s.db.exec("BEGIN;", "beginning a read");
  // The snapshot starts with the first read.
  if (st) {
    auto n = s.db.query_int("SELECT COUNT(*) FROM checkpoints;", "beginning a read");
    if (!n) st = n.status();
  }
  if (!st) {
    if (!sqlite3_get_autocommit(s.db.handle())) (void)s.db.exec("ROLLBACK;", "ending a read");
    s.read_depth = 0;
  }
  return st;
}

void ScanStore::end_read() {
  Impl& s = *impl_;
  if (s.read_depth == 0) return;
  if (--s.read_depth == 0 && !sqlite3_get_autocommit(s.db.handle()))
    (void)s.db.exec("COMMIT;", "ending a read");
}

Result<StoredChunk> ScanStore::read_chunk(const ChunkKey& key, bool include_staged) {
  Impl& s = *impl_;
  const std::string ctx = "reading chunk " + to_string(key);
  for (int pass = include_staged ? 0 : 1; pass < 2; ++pass) {
    const bool staged = pass == 0;
    auto st = s.db.prepare(std::string("SELECT ") + kChunkColumns + ", " +
                               (staged ? "0" : "checkpoint_id") + ", data FROM " +
                               (staged ? "chunk_staging" : "chunks") +
                               " WHERE x = ? AND y = ? AND z = ?;",
                           ctx);
    if (!st) return st.status();
    st->bind(1, key.x).bind(2, key.y).bind(3, key.z);
    auto row = st->step(ctx);
    if (!row) return row.status();
    if (!*row) continue;
    StoredChunk out;
    DF_RETURN_IF_ERROR(s.decode_chunk_row(*st, staged, &out));
    return out;
  }
  return not_found(s.path + ": no chunk " + to_string(key));
}

Result<std::vector<ChunkInfo>> ScanStore::list_chunks(bool include_staged) {
  Impl& s = *impl_;
  std::vector<ChunkInfo> out;
  for (int pass = 0; pass < (include_staged ? 2 : 1); ++pass) {
    const bool staged = pass == 1;
    const std::string ctx = staged ? "listing staged chunks" : "listing chunks";
    auto st = s.db.prepare(std::string("SELECT ") + kChunkColumns + ", " +
                               (staged ? "0" : "checkpoint_id") + ", length(data) FROM " +
                               (staged ? "chunk_staging" : "chunks") + " ORDER BY x, y, z;",
                           ctx);
    if (!st) return st.status();
    for (;;) {
      auto row = st->step(ctx);
      if (!row) return row.status();
      if (!*row) break;
      ChunkInfo info;
      info.key = {static_cast<int32_t>(st->int64(0)), static_cast<int32_t>(st->int64(1)),
                  static_cast<int32_t>(st->int64(2))};
      info.point_count = static_cast<uint32_t>(st->int64(3));
      info.bounds_m.setEmpty();
      if (!st->is_null(4)) {
        info.bounds_m.min() = Eigen::Vector3f(st->real(4), st->real(5), st->real(6));
        info.bounds_m.max() = Eigen::Vector3f(st->real(7), st->real(8), st->real(9));
      }
      info.last_touched_frame = static_cast<uint32_t>(st->int64(10));
      info.checkpoint_id = st->int64(11);
      info.blob_bytes = static_cast<size_t>(st->int64(12));
      out.push_back(info);
    }
  }
  return out;
}

Status ScanStore::for_each_chunk(const std::function<Status(const ChunkInfo&, PointArrays&)>& fn,
                                 const ChunkFilter& filter) {
  Impl& s = *impl_;
  std::string sql = std::string("SELECT ") + kChunkColumns + ", checkpoint_id, data FROM chunks";
  if (filter.bbox_m)
    sql += " WHERE max_x >= ? AND min_x <= ? AND max_y >= ? AND min_y <= ? AND max_z >= ? AND "
           "min_z <= ?";
  sql += " ORDER BY x, y, z;";
  auto st = s.db.prepare(sql, "reading chunks");
  if (!st) return st.status();
  if (filter.bbox_m) {
    for (int i = 0; i < 3; ++i) {
      st->bind(1 + 2 * i, static_cast<double>(filter.bbox_m->min()[i]));
      st->bind(2 + 2 * i, static_cast<double>(filter.bbox_m->max()[i]));
    }
  }
  StoredChunk chunk;
  for (;;) {
    auto row = st->step("reading chunks");
    if (!row) return row.status();
    if (!*row) break;
    Status decoded = s.decode_chunk_row(*st, false, &chunk);
    if (!decoded) {
      if (!filter.on_damaged) return decoded;
      filter.on_damaged(decoded);
      continue;
    }
    DF_RETURN_IF_ERROR(fn(chunk.info, chunk.chunk.points));
  }
  return Status::ok();
}

Result<std::vector<PoseRecord>> ScanStore::read_poses() {
  Impl& s = *impl_;
  const std::string ctx = "reading poses";
  auto st = s.db.prepare(
      "SELECT frame_id, utime, T_world_cam, registered, fitness, rmse_m, correspondences FROM poses "
      "WHERE frame_id <= (SELECT COALESCE(MAX(last_frame_id), 0) FROM checkpoints) "
      "ORDER BY frame_id;",
      ctx);
  if (!st) return st.status();
  std::vector<PoseRecord> out;
  for (;;) {
    auto row = st->step(ctx);
    if (!row) return row.status();
    if (!*row) break;
    PoseRecord p;
    p.frame_id = static_cast<uint32_t>(st->int64(0));
    p.utime = st->int64(1);
    DF_RETURN_IF_ERROR(decode_pose(st->blob(2), st->blob_size(2),
                                   s.path + ": pose of frame " + std::to_string(p.frame_id),
                                   &p.T_world_cam));
    p.registered = st->int64(3) != 0;
    p.fitness = st->real(4);
    p.rmse_m = st->real(5);
    p.correspondences = static_cast<uint32_t>(st->int64(6));
    out.push_back(p);
  }
  return out;
}

Result<std::vector<KeyframeInfo>> ScanStore::list_keyframes() {
  Impl& s = *impl_;
  const std::string ctx = "listing keyframes";
  auto st = s.db.prepare(
      "SELECT frame_id, utime, width, height, T_world_cam, length(depth), "
      "COALESCE(length(color), 0) FROM keyframes "
      "WHERE frame_id <= (SELECT COALESCE(MAX(last_frame_id), 0) FROM checkpoints) "
      "ORDER BY frame_id;",
      ctx);
  if (!st) return st.status();
  std::vector<KeyframeInfo> out;
  for (;;) {
    auto row = st->step(ctx);
    if (!row) return row.status();
    if (!*row) break;
    KeyframeInfo k;
    k.frame_id = static_cast<uint32_t>(st->int64(0));
    k.utime = st->int64(1);
    k.width = static_cast<int>(st->int64(2));
    k.height = static_cast<int>(st->int64(3));
    DF_RETURN_IF_ERROR(decode_pose(st->blob(4), st->blob_size(4),
                                   s.path + ": pose of keyframe " + std::to_string(k.frame_id),
                                   &k.T_world_cam));
    k.depth_bytes = static_cast<size_t>(st->int64(5));
    k.color_bytes = static_cast<size_t>(st->int64(6));
    out.push_back(k);
  }
  return out;
}

Result<Keyframe> ScanStore::read_keyframe(uint32_t frame_id) {
  Impl& s = *impl_;
  const std::string ctx = "reading keyframe " + std::to_string(frame_id);
  const std::string what = s.path + ": keyframe " + std::to_string(frame_id);
  auto st = s.db.prepare(
      "SELECT frame_id, utime, sensor_serial, width, height, fx, fy, cx, cy, T_world_cam, depth, "
      "color FROM keyframes WHERE frame_id = ?;",
      ctx);
  if (!st) return st.status();
  st->bind(1, frame_id);
  auto row = st->step(ctx);
  if (!row) return row.status();
  if (!*row) return not_found(s.path + ": no keyframe " + std::to_string(frame_id));
  Keyframe k;
  k.frame_id = frame_id;
  k.utime = st->int64(1);
  k.sensor_serial = st->text(2);
  k.intrinsics.width = static_cast<int>(st->int64(3));
  k.intrinsics.height = static_cast<int>(st->int64(4));
  k.intrinsics.fx = st->real(5);
  k.intrinsics.fy = st->real(6);
  k.intrinsics.cx = st->real(7);
  k.intrinsics.cy = st->real(8);
  if (!k.intrinsics.valid()) return corrupt(what + ": invalid intrinsics");
  DF_RETURN_IF_ERROR(decode_pose(st->blob(9), st->blob_size(9), what + " pose", &k.T_world_cam));
  DF_RETURN_IF_ERROR(s.codec.decode_depth(st->blob(10), st->blob_size(10), what + " depth", &k.depth));
  if (k.depth.width != k.intrinsics.width || k.depth.height != k.intrinsics.height)
    return corrupt(what + ": depth is " + std::to_string(k.depth.width) + "x" +
                   std::to_string(k.depth.height) + ", intrinsics say " +
                   std::to_string(k.intrinsics.width) + "x" + std::to_string(k.intrinsics.height));
  if (!st->is_null(11)) {
    DF_RETURN_IF_ERROR(s.codec.decode_color(st->blob(11), st->blob_size(11), what + " colour", &k.color));
    if (k.color.width != k.depth.width || k.color.height != k.depth.height)
      return corrupt(what + ": colour and depth sizes differ");
  }
  return k;
}

Result<std::optional<CheckpointRecord>> ScanStore::last_checkpoint() {
  Impl& s = *impl_;
  auto st = s.db.prepare(std::string("SELECT ") + kCheckpointColumns +
                             " FROM checkpoints ORDER BY id DESC LIMIT 1;",
                         "reading the last checkpoint");
  if (!st) return st.status();
  auto row = st->step("reading the last checkpoint");
  if (!row) return row.status();
  if (!*row) return std::optional<CheckpointRecord>();
  auto rec = s.read_checkpoint_row(*st);
  if (!rec) return rec.status();
  return std::optional<CheckpointRecord>(std::move(rec).value());
}

Result<std::vector<CheckpointRecord>> ScanStore::checkpoints() {
  Impl& s = *impl_;
  auto st = s.db.prepare(std::string("SELECT ") + kCheckpointColumns + " FROM checkpoints ORDER BY id;",
                         "reading checkpoints");
  if (!st) return st.status();
  std::vector<CheckpointRecord> out;
  for (;;) {
    auto row = st->step("reading checkpoints");
    if (!row) return row.status();
    if (!*row) break;
    auto rec = s.read_checkpoint_row(*st);
    if (!rec) return rec.status();
    out.push_back(std::move(rec).value());
  }
  return out;
}

Result<StoreSummary> ScanStore::summary() {
  Impl& s = *impl_;
  ScopedRead snapshot(*this);
  DF_RETURN_IF_ERROR(snapshot.status());
  StoreSummary sum;
  sum.path = s.path;
  sum.schema_version = s.schema_version;
  auto meta = metadata();
  if (!meta) return meta.status();
  sum.metadata = *meta;
  auto config = config_toml();
  if (!config) return config.status();
  sum.has_config = config->has_value();
  const std::string ctx = "summarising chunks";
  auto st = s.db.prepare(
      "SELECT COUNT(*), COALESCE(SUM(point_count), 0), MIN(min_x), MIN(min_y), MIN(min_z), "
      "MAX(max_x), MAX(max_y), MAX(max_z), COALESCE(SUM(length(data)), 0) FROM chunks;",
      ctx);
  if (!st) return st.status();
  auto row = st->step(ctx);
  if (!row) return row.status();
  sum.chunk_count = static_cast<size_t>(st->int64(0));
  sum.point_count = static_cast<uint64_t>(st->int64(1));
  sum.extent_m.setEmpty();
  if (!st->is_null(2)) {
    sum.extent_m.min() = Eigen::Vector3f(st->real(2), st->real(3), st->real(4));
    sum.extent_m.max() = Eigen::Vector3f(st->real(5), st->real(6), st->real(7));
  }
  sum.chunk_bytes = static_cast<uint64_t>(st->int64(8));
  auto count = [&](const char* sql, const char* what) -> Result<int64_t> {
    return s.db.query_int(sql, what);
  };
  const char* kLast = "(SELECT COALESCE(MAX(last_frame_id), 0) FROM checkpoints)";
  auto poses = count((std::string("SELECT COUNT(*) FROM poses WHERE frame_id <= ") + kLast).c_str(),
                     "counting poses");
  if (!poses) return poses.status();
  sum.pose_count = static_cast<size_t>(*poses);
  auto kf = count((std::string("SELECT COUNT(*) FROM keyframes WHERE frame_id <= ") + kLast).c_str(),
                  "counting keyframes");
  if (!kf) return kf.status();
  sum.keyframe_count = static_cast<size_t>(*kf);
  auto kfb = count("SELECT COALESCE(SUM(length(depth) + COALESCE(length(color), 0)), 0) FROM keyframes;",
                   "measuring keyframes");
  if (!kfb) return kfb.status();
  sum.keyframe_bytes = static_cast<uint64_t>(*kfb);
  auto cps = count("SELECT COUNT(*) FROM checkpoints;", "counting checkpoints");
  if (!cps) return cps.status();
  sum.checkpoint_count = static_cast<size_t>(*cps);
  auto staged = count("SELECT COUNT(*) FROM chunk_staging;", "counting staged chunks");
  if (!staged) return staged.status();
  sum.staged_chunk_count = static_cast<size_t>(*staged);
  auto last = last_checkpoint();
  if (!last) return last.status();
  sum.last_checkpoint = *last;
  sum.file_bytes = file_size(s.path);
  sum.wal_bytes = file_size(s.path + "-wal");
  return sum;
}

Result<IntegrityReport> ScanStore::integrity_check(bool check_blobs) {
  Impl& s = *impl_;
  IntegrityReport rep;
  ScopedRead snapshot(*this);
  if (!snapshot.status()) rep.problems.push_back(snapshot.status().message());
  {
    auto st = s.db.prepare("PRAGMA integrity_check(50);", "checking integrity");
    if (!st) {
      rep.problems.push_back(st.status().message());
      return rep;
    }
    for (;;) {
      auto row = st->step("PRAGMA integrity_check");
      if (!row) {
        rep.problems.push_back(row.status().message());
        break;
      }
      if (!*row) break;
      const std::string line = st->text(0);
      if (line != "ok") rep.problems.push_back(s.path + ": sqlite integrity_check: " + line);
    }
  }
  if (!check_blobs) return rep;
  // Every chunk blob: decodes, checksums match, and its row's count and bounds agree.
  for (const char* table : {"chunks", "chunk_staging"}) {
    const bool staged = std::strcmp(table, "chunk_staging") == 0;
    auto st = s.db.prepare(std::string("SELECT ") + kChunkColumns + ", " +
                               (staged ? "0" : "checkpoint_id") + ", data FROM " + table +
                               " ORDER BY x, y, z;",
                           "checking chunks");
    if (!st) {
      rep.problems.push_back(st.status().message());
      continue;
    }
    StoredChunk c;
    for (;;) {
      auto row = st->step(std::string("reading ") + table);
      if (!row) {
        rep.problems.push_back(row.status().message());
        break;
      }
      if (!*row) break;
      ++rep.chunks_checked;
      Status ok = s.decode_chunk_row(*st, staged, &c);
      if (ok && c.info.point_count > 0) {
        const Eigen::AlignedBox3f box = bounds_of(c.chunk.points);
        if (!box.min().isApprox(c.info.bounds_m.min(), 1e-5f) ||
            !box.max().isApprox(c.info.bounds_m.max(), 1e-5f))
          ok = corrupt(s.path + ": chunk " + to_string(c.info.key) +
                       ": stored bounds disagree with its points");
      }
      if (!ok) rep.problems.push_back(ok.message());
    }
  }
  {
    auto st = s.db.prepare("SELECT frame_id FROM keyframes ORDER BY frame_id;", "checking keyframes");
    std::vector<uint32_t> ids;
    if (!st) {
      rep.problems.push_back(st.status().message());
    } else {
      for (;;) {
        auto row = st->step("listing keyframes");
        if (!row) {
          rep.problems.push_back(row.status().message());
          break;
        }
        if (!*row) break;
        ids.push_back(static_cast<uint32_t>(st->int64(0)));
      }
    }
    for (uint32_t id : ids) {
      ++rep.keyframes_checked;
      auto k = read_keyframe(id);
      if (!k) rep.problems.push_back(k.status().message());
    }
  }
  {
    auto st = s.db.prepare("SELECT frame_id, T_world_cam FROM poses ORDER BY frame_id;", "checking poses");
    if (!st) {
      rep.problems.push_back(st.status().message());
    } else {
      for (;;) {
        auto row = st->step("reading poses");
        if (!row) {
          rep.problems.push_back(row.status().message());
          break;
        }
        if (!*row) break;
        ++rep.poses_checked;
        Pose T;
        Status ok = decode_pose(st->blob(1), st->blob_size(1),
                                s.path + ": pose of frame " + std::to_string(st->int64(0)), &T);
        if (!ok) rep.problems.push_back(ok.message());
      }
    }
  }
  auto cps = checkpoints();
  if (!cps) rep.problems.push_back(cps.status().message());
  auto meta = metadata();
  if (!meta) rep.problems.push_back(meta.status().message());
  return rep;
}

Status ScanStore::copy_to(const std::string& path) {
  Impl& s = *impl_;
  if (file_exists(path)) return invalid_argument(path + ": already exists");
  const std::string ctx = "copying to " + path;
  auto st = s.db.prepare("VACUUM INTO ?;", ctx);
  if (!st) return st.status();
  st->bind(1, path);
  Status done = st->run(ctx);
  if (!done) ::unlink(path.c_str());
  return done;
}

Status ScanStore::compact() {
  Impl& s = *impl_;
  DF_RETURN_IF_ERROR(s.require_writable("compact"));
  if (s.in_checkpoint) return invalid_argument(s.path + ": compact inside a checkpoint");
  return s.db.exec("PRAGMA incremental_vacuum;", "returning free pages");
}

}  // namespace depthfuse::store
