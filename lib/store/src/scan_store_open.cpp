// Opening a scan file: the header check before SQLite sees the file, the one-writer lock, creating
// a new scan (complete or not at all), migrating an older schema, and recovering after a crash (the
// file becomes exactly its last checkpoint). Runs on the thread that opens the store: the fusion
// daemon's worker thread when a scan starts or resumes, the CLI's main thread for readers and
// refine.
#include <fcntl.h>
#include <sys/file.h>
#include <sys/stat.h>
#include <unistd.h>

#include <cerrno>
#include <cstring>

#include "depthfuse/base/clock.hpp"
#include "depthfuse/base/errno_text.hpp"
#include "depthfuse/input_file.hpp"
#include "scan_store_internal.hpp"
#include "schema.hpp"

namespace depthfuse::store {

namespace {

// Checks that `path` looks like an SQLite file before SQLite sees it, so that an empty, foreign or
// truncated file gets an error naming the problem.
Status check_file_header(const std::string& path) {
  // Only a regular file: a FIFO given as a scan file would block the open, and SQLite after it.
  auto file = InputFile::open(path, "scan file");
  if (!file) {
    if (file.status().code() == StatusCode::kNotFound) return not_found(path + ": no such scan file");
    return file.status();
  }
  const struct stat& st = file->info();
  unsigned char h[100];
  const ssize_t n = ::pread(file->fd(), h, sizeof(h), 0);
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

// WAL (persistent in the file): readers never block the writer, and a crash in the middle of a
// transaction leaves the last commit. `path` names the scan in the error.
Status enable_wal(sql::Database& db, const std::string& path) {
  auto mode = db.prepare("PRAGMA journal_mode = WAL;", "enabling WAL");
  if (!mode) return mode.status();
  auto row = mode->step();
  if (!row) return row.status();
  if (!*row || mode->row().text(0) != "wal")
    return io_error(path + ": the file system does not support WAL mode");
  return Status::ok();
}

Status already_exists(const std::string& path) {
  return invalid_argument(path + ": already exists; a new scan needs a new file");
}

}  // namespace

// A new scan appears under its name only complete: the schema is built in a temporary file
// beside it, which is then linked into place (link fails if the name exists, so two creators
// cannot both win). A crash during creation leaves no half-made scan file behind the name.
Status ScanStore::Impl::create_new() {
  if (file_exists(path)) return already_exists(path);
  const std::string tmp = path + ".creating-" + std::to_string(::getpid());
  auto cleanup = [&] {
    for (const char* suffix : {"", "-journal", "-wal", "-shm"}) ::unlink((tmp + suffix).c_str());
  };
  cleanup();
  Status st;
  {
    sql::Database fresh;
    st = fresh.open(tmp, SQLITE_OPEN_READWRITE | SQLITE_OPEN_CREATE | SQLITE_OPEN_NOMUTEX);
    if (st) st = fresh.exec("PRAGMA synchronous = FULL;", "setting synchronous");
    // Pages freed by deleted chunks can be returned to the file system (ScanStore::compact).
    if (st) st = fresh.exec("PRAGMA auto_vacuum = INCREMENTAL;", "setting auto_vacuum");
    if (st) {
      st = fresh.transaction("creating the scan", [&]() -> Status {
        DF_RETURN_IF_ERROR(schema::create_current(fresh));
        auto meta = fresh.prepare("INSERT INTO meta (key, value) VALUES ('created_utime', ?), "
                                  "('chunk_size_m', '0.5');",
                                  "creating the scan");
        if (!meta) return meta.status();
        return meta->bind(1, std::to_string(now_utime())).run();
      });
    }
    if (st) st = enable_wal(fresh, path);
  }
  if (st && ::link(tmp.c_str(), path.c_str()) != 0)
    st = errno == EEXIST ? already_exists(path) : io_error(path + ": cannot create: " + errno_text());
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

// One writer per file: an advisory lock on a descriptor of our own, held until the store closes.
Status ScanStore::Impl::lock_for_writing() {
  lock_fd = ::open(path.c_str(), O_RDWR | O_CLOEXEC);
  if (lock_fd < 0) return io_error(path + ": cannot open for writing: " + errno_text());
  if (::flock(lock_fd, LOCK_EX | LOCK_NB) != 0) {
    if (errno == EWOULDBLOCK)
      return unavailable(path + ": another process is writing this scan (the fusion daemon?); "
                                "open it read-only or stop the writer");
    return io_error(path + ": cannot lock: " + errno_text());
  }
  return Status::ok();
}

Status ScanStore::Impl::open_existing() {
  DF_RETURN_IF_ERROR(check_file_header(path));
  if (writable()) DF_RETURN_IF_ERROR(lock_for_writing());
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
    DF_RETURN_IF_ERROR(set_synchronous("FULL"));
    const Status st = db.transaction(
        "migrating", [&] { return schema::migrate(db, static_cast<int>(*version)); });
    if (!st) return st.with_context("migrating from schema " + std::to_string(*version));
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
    // Debian's SQLite zeroes every freed page (SQLITE_SECURE_DELETE): a checkpoint that drops 30 s
    // of the frame log would write all of it again, into the WAL and then the file, while it holds
    // the store (docs/history/results-sessions-1-33.md, session 32). A scan is not secret; FAST
    // still clears freed b-tree cells where that costs no extra I/O, but leaves freed overflow
    // pages as they are.
    DF_RETURN_IF_ERROR(db.exec("PRAGMA secure_delete = FAST;", "setting secure_delete"));
    DF_RETURN_IF_ERROR(enable_wal(db, path));
    DF_RETURN_IF_ERROR(recover());
    DF_RETURN_IF_ERROR(set_synchronous("NORMAL"));
  }
  return Status::ok();
}

// A writer reopening the file drops what was written after the last checkpoint: staged chunks,
// and poses and keyframes of later frames. The file is then exactly the last checkpoint plus the
// frame redo log's records after it, which a resume replays.
Status ScanStore::Impl::recover() {
  DF_RETURN_IF_ERROR(set_synchronous("FULL"));
  return in_transaction("discarding work after the last checkpoint", [&]() -> Status {
    DF_RETURN_IF_ERROR(db.exec("DELETE FROM chunk_staging;", "discarding staged chunks"));
    report.discarded_staged_chunks = db.changes();
    DF_RETURN_IF_ERROR(db.exec("DELETE FROM poses WHERE NOT (" + kCommittedFrames + ");",
                               "discarding poses"));
    report.discarded_poses = db.changes();
    DF_RETURN_IF_ERROR(db.exec("DELETE FROM keyframes WHERE NOT (" + kCommittedFrames + ");",
                               "discarding keyframes"));
    report.discarded_keyframes = db.changes();
    // Log records after the checkpoint stay: a resume replays them (and re-records their poses
    // and keyframes). Those it covers were left by a log commit that raced its checkpoint.
    DF_RETURN_IF_ERROR(db.exec("DELETE FROM frame_log WHERE " + kCommittedFrames + ";",
                               "discarding covered frame log records"));
    report.discarded_log_records = db.changes();
    return Status::ok();
  });
}

Result<std::unique_ptr<ScanStore>> ScanStore::another_connection(const StoreOptions& options) const {
  const Impl& primary = *impl_;
  auto impl = std::make_unique<Impl>(options.compression_level);
  impl->path = primary.path;
  impl->mode = primary.writable() ? OpenMode::kReadWrite : OpenMode::kReadOnly;
  impl->options = options;
  impl->schema_version = primary.schema_version;
  const int flags = (primary.writable() ? SQLITE_OPEN_READWRITE : SQLITE_OPEN_READONLY) |
                    SQLITE_OPEN_NOMUTEX;
  DF_RETURN_IF_ERROR(impl->db.open(impl->path, flags));
  sqlite3_busy_timeout(impl->db.handle(), options.busy_timeout_ms);
  if (impl->writable()) {
    // Per connection, as the first one's (open_existing).
    DF_RETURN_IF_ERROR(impl->db.exec("PRAGMA secure_delete = FAST;", "setting secure_delete"));
    DF_RETURN_IF_ERROR(impl->set_synchronous("NORMAL"));
  }
  return std::unique_ptr<ScanStore>(new ScanStore(std::move(impl)));
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

}  // namespace depthfuse::store
