// Internal: a thin RAII layer over the SQLite C API that turns result codes into Status values
// naming the file, the operation and SQLite's own explanation. A statement keeps the purpose it was
// prepared for, so that every error it reports later names it.
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

// The columns of the row a statement stands on; valid until the statement steps again.
class Row {
 public:
  explicit Row(sqlite3_stmt* stmt) : stmt_(stmt) {}

  int64_t int64(int col) const { return sqlite3_column_int64(stmt_, col); }
  double real(int col) const { return sqlite3_column_double(stmt_, col); }
  bool is_null(int col) const { return sqlite3_column_type(stmt_, col) == SQLITE_NULL; }
  std::string text(int col) const {
    const auto* p = sqlite3_column_text(stmt_, col);
    return p ? std::string(reinterpret_cast<const char*>(p),
                           static_cast<size_t>(sqlite3_column_bytes(stmt_, col)))
             : std::string();
  }
  const void* blob(int col) const { return sqlite3_column_blob(stmt_, col); }
  size_t blob_size(int col) const { return static_cast<size_t>(sqlite3_column_bytes(stmt_, col)); }

 private:
  sqlite3_stmt* stmt_;
};

class Statement {
 public:
  Statement() = default;
  Statement(sqlite3* db, sqlite3_stmt* stmt, std::string path, std::string context)
      : db_(db), stmt_(stmt), path_(std::move(path)), context_(std::move(context)) {}
  ~Statement() { sqlite3_finalize(stmt_); }
  Statement(Statement&& o) noexcept { *this = std::move(o); }
  Statement& operator=(Statement&& o) noexcept {
    std::swap(db_, o.db_);
    std::swap(stmt_, o.stmt_);
    std::swap(path_, o.path_);
    std::swap(context_, o.context_);
    std::swap(status_, o.status_);
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
  // The blob must outlive the step.
  Statement& bind_blob(int index, const void* data, size_t size) {
    sqlite3_bind_blob64(stmt_, index, data, size, SQLITE_STATIC);
    return *this;
  }
  Statement& bind_blob(int index, const std::vector<uint8_t>& v) {
    return bind_blob(index, v.data(), v.size());
  }
  Statement& bind_null(int index) { sqlite3_bind_null(stmt_, index); return *this; }

  // Steps once: true when a row is available (read it with row()), false when done.
  Result<bool> step();
  // Steps once and expects completion (INSERT/UPDATE/DELETE); `context` overrides the purpose
  // given to prepare, e.g. to name the row.
  Status run() { return run(context_); }
  Status run(const std::string& context);
  Row row() const { return Row(stmt_); }

  // The rows of a query, for a range-for:
  //
  //   for (const sql::Row& row : stmt.rows()) { ... }
  //   DF_RETURN_IF_ERROR(stmt.status());
  //
  // An error ends the loop like the last row does; status() tells the two apart.
  class RowIterator {
   public:
    explicit RowIterator(Statement* st) : st_(st), row_(st ? st->stmt_ : nullptr) { advance(); }
    const Row& operator*() const { return row_; }
    RowIterator& operator++() {
      advance();
      return *this;
    }
    bool operator!=(const RowIterator& o) const { return st_ != o.st_; }

   private:
    void advance() {
      if (st_ && !st_->next()) st_ = nullptr;
    }
    Statement* st_;
    Row row_;
  };
  struct Rows {
    Statement* st;
    RowIterator begin() const { return RowIterator(st); }
    RowIterator end() const { return RowIterator(nullptr); }
  };
  Rows rows() {
    status_ = Status::ok();
    return Rows{this};
  }
  // Ok unless the last rows() loop ended on an error.
  const Status& status() const { return status_; }

 private:
  // One step of rows(): false at the end and on an error (kept in status_).
  bool next();

  sqlite3* db_ = nullptr;
  sqlite3_stmt* stmt_ = nullptr;
  std::string path_;
  std::string context_;
  Status status_;
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
  // Runs fn in a transaction of its own, taking the write lock up front (BEGIN IMMEDIATE): commits
  // when fn succeeds, rolls back when anything fails.
  template <typename Fn>
  Status transaction(const std::string& context, Fn&& fn) {
    DF_RETURN_IF_ERROR(exec("BEGIN IMMEDIATE;", context));
    Status st = fn();
    if (st) st = exec("COMMIT;", context);
    if (!st) rollback(context);
    return st;
  }
  // Abandons the open transaction, if there is one (a failed COMMIT may have ended it already).
  void rollback(const std::string& context) {
    if (in_transaction()) (void)exec("ROLLBACK;", context);
  }
  // `context` names the statement's purpose in its errors, e.g. "reading poses".
  Result<Statement> prepare(const std::string& sql, const std::string& context);
  // Every row of a query, each made into a T by `of` (const Row& -> Result<T>); the first error
  // of the query or of `of` ends it.
  template <typename T, typename Fn>
  Result<std::vector<T>> collect(const std::string& sql, const std::string& context, Fn&& of) {
    auto st = prepare(sql, context);
    if (!st) return st.status();
    std::vector<T> out;
    for (const Row& row : st->rows()) {
      Result<T> item = of(row);
      if (!item) return item.status();
      out.push_back(std::move(item).value());
    }
    DF_RETURN_IF_ERROR(st->status());
    return out;
  }
  // Single integer result of a query or pragma (e.g. "PRAGMA user_version").
  Result<int64_t> query_int(const std::string& sql, const std::string& context);
  Status error(int rc, const std::string& context) const { return make_status(db_, rc, path_, context); }
  // Rows changed by the last INSERT/UPDATE/DELETE.
  size_t changes() const { return static_cast<size_t>(sqlite3_changes(db_)); }
  // Inside a transaction (SQLite is not in autocommit mode).
  bool in_transaction() const { return !sqlite3_get_autocommit(db_); }

 private:
  sqlite3* db_ = nullptr;
  std::string path_;
};

}  // namespace depthfuse::store::sql
