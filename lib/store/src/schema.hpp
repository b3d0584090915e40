// Internal: the schema of the scan file and the migrations from older versions.
#pragma once

#include "sqlite_db.hpp"

namespace depthfuse::store::schema {

// Creates the current schema in an empty database (inside the caller's transaction).
Status create_current(sql::Database& db);

// Brings a file of an older version up to kSchemaVersion, step by step, inside the caller's
// transaction (a failed migration leaves the file as it was).
Status migrate(sql::Database& db, int from_version);

// Tables the current schema must have (a quick structural check on open).
extern const char* const kTables[];

}  // namespace depthfuse::store::schema
