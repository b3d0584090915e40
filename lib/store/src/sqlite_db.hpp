// Internal: a thin RAII layer over the SQLite C API that turns result codes into Status values
// naming the file, the operation and SQLite's own explanation.
#pragma once

#include <sqlite3.h>

#include <cstdint>
#include <string>
#include <vector>

#include "depthfuse/status.hpp"

namespace depthfuse::store::sql {

// Maps an SQLite result code to a StatusCode: full disk and I/O errors -> kIoError, a damaged or
// foreign file -> kCorrupt, locks -> kUnavailable.
StatusCode status_code_for(int rc);
// "<path>: <context>: <sqlite message> (<code name>)"
Status make_status(sqlite3* db, int rc, const std::string& path, const std::string& context);

class Statement {
 public:
  Statement() = default;
  Statement(sqlite3* db, sqlite3_stmt* stmt, std::string path, std::string sql)
      : db_(db), stmt_(stmt), path_(std::move(path)), sql_(std::move(sql)) {}
  ~Statement() { sqlite3_finalize(stmt_); }
  Statement(Statement&& o) noexcept { *this = std::move(o); }
  Statement& operator=(Statement&& o) noexcept {
    std::swap(db_, o.db_);
    std::swap(stmt_, o.stmt_);
    std::swap(path_, o.path_);
    std::swap(sql_, o.sql_);
    return *this;
  }
  Statement(const Statement&) = delete;
  Statement& operator=(const Statement&) = delete;

  Statement& bind(int index, int64_t v) { sqlite3_bind_int64(stmt_, index, v); return *this; }
  Statement& bind(int index, int v) { sqlite3_bind_int64(stmt_, index, v); return *this; }
  Statement& bind(int index, uint32_t v) { sqlite3_bind_int64(stmt_, index, v); return *this; }
  Statement& bind(int index, double v) { sqlite3_bind_double(stmt_, index, v); return *this; }
  Statement& bind(int index, const std::string& v) {
    sqlite3_bind_text(stmt_, index, v.data(), static_cast<int>(v.size()), SQLITE_TRANSIENT);
    return *this;
  }
  // The blob must outlive step().
  Statement& bind_blob(int index, const void* data, size_t size) {
    sqlite3_bind_blob64(stmt_, index, data, size, SQLITE_STATIC);
    return *this;
  }
  Statement& bind_blob(int index, const std::vector<uint8_t>& v) {
    return bind_blob(index, v.data(), v.size());
  }
  Statement& bind_null(int index) { sqlite3_bind_null(stmt_, index); return *this; }

  // true: a row is available; false: done. Errors name the statement's purpose.
  Result<bool> step(const std::string& context);
  // Steps once and expects completion (INSERT/UPDATE/DELETE).
  Status run(const std::string& context);
  void reset() {
    sqlite3_reset(stmt_);
    sqlite3_clear_bindings(stmt_);
  }

  int64_t int64(int col) const { return sqlite3_column_int64(stmt_, col); }
  double real(int col) const { return sqlite3_column_double(stmt_, col); }
  bool is_null(int col) const { return sqlite3_column_type(stmt_, col) == SQLITE_NULL; }
  std::string text(int col) const {
    const auto* p = sqlite3_column_text(stmt_, col);
    return p ? std::string(reinterpret_cast<const char*>(p),
                           static_cast<size_t>(sqlite3_column_bytes(stmt_, col)))
             : std::string();
  }
  // Valid until the next step/reset.
  const void* blob(int col) const { return sqlite3_column_blob(stmt_, col); }
  size_t blob_size(int col) const { return static_cast<size_t>(sqlite3_column_bytes(stmt_, col)); }

 private:
  sqlite3* db_ = nullptr;
  sqlite3_stmt* stmt_ = nullptr;
  std::string path_;
  std::string sql_;
};

class Database {
 public:
  Database() = default;
  ~Database() { close(); }
  Database(const Database&) = delete;
  Database& operator=(const Database&) = delete;

  Status open(const std::string& path, int flags);
  void close();
  bool is_open() const { return db_ != nullptr; }
  sqlite3* handle() const { return db_; }
  const std::string& path() const { return path_; }

  Status exec(const std::string& sql, const std::string& context);
  Result<Statement> prepare(const std::string& sql, const std::string& context);
  // Single integer result of a query or pragma (e.g. "PRAGMA user_version").
  Result<int64_t> query_int(const std::string& sql, const std::string& context);
  Status error(int rc, const std::string& context) const { return make_status(db_, rc, path_, context); }

 private:
  sqlite3* db_ = nullptr;
  std::string path_;
};

}  // namespace depthfuse::store::sql
