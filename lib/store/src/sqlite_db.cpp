// The SQLite layer's error mapping and stepping. A Database and its statements belong to the one
// thread that uses the ScanStore (connections are opened with SQLITE_OPEN_NOMUTEX).
#include "sqlite_db.hpp"

#include "depthfuse/base/errno_text.hpp"

namespace depthfuse::store::sql {

StatusCode status_code_for(int rc) {
  switch (rc & 0xFF) {
    case SQLITE_OK:
    case SQLITE_ROW:
    case SQLITE_DONE: return StatusCode::kOk;
    case SQLITE_FULL:
    case SQLITE_IOERR:
    case SQLITE_READONLY:
    case SQLITE_CANTOPEN:
    case SQLITE_PERM:
    case SQLITE_NOLFS: return StatusCode::kIoError;
    case SQLITE_CORRUPT:
    case SQLITE_NOTADB:
    case SQLITE_FORMAT: return StatusCode::kCorrupt;
    case SQLITE_BUSY:
    case SQLITE_LOCKED: return StatusCode::kUnavailable;
    case SQLITE_CONSTRAINT:
    case SQLITE_MISMATCH:
    case SQLITE_RANGE:
    case SQLITE_TOOBIG: return StatusCode::kInvalidArgument;
    default: return StatusCode::kInternal;
  }
}

Status make_status(sqlite3* db, int rc, const std::string& path, const std::string& context) {
  std::string msg = path + ": " + context + ": ";
  const int primary = rc & 0xFF;
  if (primary == SQLITE_FULL) {
    msg += "disk full (no space left for the scan file)";
  } else if (primary == SQLITE_NOTADB) {
    msg += "not an SQLite database (the file is damaged or not a scan file)";
  } else if (primary == SQLITE_CORRUPT) {
    msg += "the file is damaged (database disk image is malformed)";
  } else {
    msg += (db && sqlite3_errcode(db) == rc) ? sqlite3_errmsg(db) : sqlite3_errstr(rc);
  }
  // The operating system's reason for an I/O error ("File too large", "No space left on device").
  if (db && (primary == SQLITE_IOERR || primary == SQLITE_FULL || primary == SQLITE_CANTOPEN)) {
    const int err = sqlite3_system_errno(db);
    if (err != 0) msg += " (" + errno_text(err) + ")";
  }
  msg += " [sqlite " + std::to_string(rc) + ": " + sqlite3_errstr(rc) + "]";
  return Status(status_code_for(rc), msg);
}

Result<bool> Statement::step() {
  const int rc = sqlite3_step(stmt_);
  if (rc == SQLITE_ROW) return true;
  if (rc == SQLITE_DONE) return false;
  return make_status(db_, rc, path_, context_);
}

bool Statement::next() {
  auto r = step();
  if (!r) status_ = r.status();
  return r.is_ok() && *r;
}

Status Statement::run(const std::string& context) {
  const int rc = sqlite3_step(stmt_);
  // The message first: resetting the statement may change what SQLite reports.
  Status st = rc == SQLITE_ROW || rc == SQLITE_DONE ? Status::ok()
                                                    : make_status(db_, rc, path_, context);
  sqlite3_reset(stmt_);
  return st;
}

Status Database::open(const std::string& path, int flags) {
  close();
  path_ = path;
  const int rc = sqlite3_open_v2(path.c_str(), &db_, flags, nullptr);
  if (rc != SQLITE_OK) {
    Status st = make_status(db_, rc, path, "cannot open");
    close();
    return st;
  }
  sqlite3_extended_result_codes(db_, 1);
  return Status::ok();
}

void Database::close() {
  if (db_) sqlite3_close_v2(db_);
  db_ = nullptr;
}

Status Database::exec(const std::string& sql, const std::string& context) {
  char* err = nullptr;
  const int rc = sqlite3_exec(db_, sql.c_str(), nullptr, nullptr, &err);
  sqlite3_free(err);
  if (rc != SQLITE_OK) return make_status(db_, rc, path_, context);
  return Status::ok();
}

Result<Statement> Database::prepare(const std::string& sql, const std::string& context) {
  sqlite3_stmt* stmt = nullptr;
  const int rc = sqlite3_prepare_v2(db_, sql.c_str(), static_cast<int>(sql.size()), &stmt, nullptr);
  if (rc != SQLITE_OK) {
    sqlite3_finalize(stmt);
    return make_status(db_, rc, path_, context);
  }
  return Statement(db_, stmt, path_, context);
}

Result<int64_t> Database::query_int(const std::string& sql, const std::string& context) {
  auto st = prepare(sql, context);
  if (!st) return st.status();
  auto row = st->step();
  if (!row) return row.status();
  if (!*row) return internal_error(path_ + ": " + context + ": no result");
  return st->row().int64(0);
}

}  // namespace depthfuse::store::sql
