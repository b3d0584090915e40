// The scan file's schema and its migrations. Runs inside ScanStore's open, on the thread that opens
// the store.
#include "schema.hpp"

#include <string>

#include "depthfuse/store/scan_store.hpp"

namespace depthfuse::store::schema {

const char* const kTables[] = {"meta", "checkpoints", "chunks", "chunk_staging", "poses",
                               "keyframes", "frame_log", "graph_keyframes", "graph", "chunk_pending", nullptr};

namespace {

// Schema 2; later versions are built by the migrations from it. Blob columns come last in each row: SQLite stores a row's columns in order
// and a big blob spills into overflow pages, so the small columns stay cheap to read.
//
// The committed chunks and the staged ones share a layout; only the column before the blob
// differs: the checkpoint that wrote a committed chunk, the time a staged one was evicted.
// Schema 6 adds the pose graph's version of the points and the row's checksum before the owner;
// schema 8's points pending for a chunk have a row per chunk and version.
std::string chunk_table(const char* name, const char* owner_column, bool with_version = false,
                        const char* primary_key = "x, y, z") {
  return std::string("\nCREATE TABLE ") + name + R"sql( (
  x INTEGER NOT NULL,
  y INTEGER NOT NULL,
  z INTEGER NOT NULL,
  point_count INTEGER NOT NULL,
  min_x REAL, min_y REAL, min_z REAL,
  max_x REAL, max_y REAL, max_z REAL,
  last_touched_frame INTEGER NOT NULL,
  )sql" + (with_version ? "version INTEGER NOT NULL DEFAULT 0,\n  checksum INTEGER,\n  " : "") +
         owner_column + R"sql( INTEGER NOT NULL,
  data BLOB NOT NULL,
  PRIMARY KEY ()sql" + primary_key + R"sql()
);
)sql";
}

std::string chunks_v2() { return chunk_table("chunks", "checkpoint_id"); }

// The tables schema 2 added to schema 1.
std::string added_in_v2() {
  return R"sql(
CREATE TABLE checkpoints (
  id INTEGER PRIMARY KEY,
  utime INTEGER NOT NULL,
  reason TEXT NOT NULL,
  last_frame_id INTEGER NOT NULL,
  frames_fused INTEGER NOT NULL,
  point_count INTEGER NOT NULL,
  chunk_count INTEGER NOT NULL,
  T_world_cam BLOB
);)sql" + chunk_table("chunk_staging", "staged_utime");
}

constexpr const char* kCreateV2 = R"sql(
CREATE TABLE meta (
  key TEXT PRIMARY KEY NOT NULL,
  value TEXT NOT NULL
);
CREATE TABLE poses (
  frame_id INTEGER PRIMARY KEY,
  utime INTEGER NOT NULL,
  T_world_cam BLOB NOT NULL,
  registered INTEGER NOT NULL DEFAULT 0,
  fitness REAL,
  rmse_m REAL,
  correspondences INTEGER
);
)sql";

// The keyframes table of schema 2, of schema 4 with the row's checksum before the images, and of
// schema 7 with the pose's anchor before them too.
std::string keyframes_table(bool with_checksum, bool with_anchor = false) {
  return std::string(R"sql(
CREATE TABLE keyframes (
  frame_id INTEGER PRIMARY KEY,
  utime INTEGER NOT NULL,
  sensor_serial TEXT NOT NULL DEFAULT '',
  width INTEGER NOT NULL,
  height INTEGER NOT NULL,
  fx REAL NOT NULL,
  fy REAL NOT NULL,
  cx REAL NOT NULL,
  cy REAL NOT NULL,
  T_world_cam BLOB NOT NULL,)sql") + (with_anchor ? "\n  graph_keyframe INTEGER," : "") +
         (with_checksum ? "\n  checksum INTEGER," : "") + R"sql(
  depth BLOB NOT NULL,
  color BLOB
);
)sql";
}

// Schema 1 -> 2:
//  - checkpoints get a table of their own (v1 kept only the last one, in meta keys
//    checkpoint_count / checkpoint_utime / checkpoint_last_frame_id);
//  - chunks record the checkpoint that wrote them (the table is rebuilt so that the new column
//    sits before the blob);
//  - chunk_staging holds chunks the memory pager evicted between checkpoints;
//  - poses carry the ICP result, keyframes an optional colour image.
Status migrate_1_to_2(sql::Database& db) {
  const std::string ctx = "migrating schema 1 to 2";
  DF_RETURN_IF_ERROR(db.exec(added_in_v2(), ctx));
  DF_RETURN_IF_ERROR(db.exec(R"sql(
INSERT INTO checkpoints (id, utime, reason, last_frame_id, frames_fused, point_count, chunk_count,
                         T_world_cam)
SELECT CAST(c.value AS INTEGER),
       COALESCE((SELECT CAST(value AS INTEGER) FROM meta WHERE key = 'checkpoint_utime'), 0),
       'migrated from schema 1',
       COALESCE((SELECT CAST(value AS INTEGER) FROM meta WHERE key = 'checkpoint_last_frame_id'), 0),
       (SELECT COUNT(*) FROM poses),
       (SELECT COALESCE(SUM(point_count), 0) FROM chunks),
       (SELECT COUNT(*) FROM chunks),
       (SELECT T_world_cam FROM poses ORDER BY frame_id DESC LIMIT 1)
FROM meta AS c WHERE c.key = 'checkpoint_count' AND CAST(c.value AS INTEGER) > 0;
)sql", ctx));
  DF_RETURN_IF_ERROR(db.exec("ALTER TABLE chunks RENAME TO chunks_v1;", ctx));
  DF_RETURN_IF_ERROR(db.exec(chunks_v2(), ctx));
  DF_RETURN_IF_ERROR(db.exec(R"sql(
INSERT INTO chunks (x, y, z, point_count, min_x, min_y, min_z, max_x, max_y, max_z,
                    last_touched_frame, checkpoint_id, data)
SELECT x, y, z, point_count, min_x, min_y, min_z, max_x, max_y, max_z, last_touched_frame,
       (SELECT COALESCE(MAX(id), 0) FROM checkpoints), data
FROM chunks_v1;
DROP TABLE chunks_v1;
ALTER TABLE poses ADD COLUMN registered INTEGER NOT NULL DEFAULT 0;
ALTER TABLE poses ADD COLUMN fitness REAL;
ALTER TABLE poses ADD COLUMN rmse_m REAL;
ALTER TABLE poses ADD COLUMN correspondences INTEGER;
ALTER TABLE keyframes ADD COLUMN color BLOB;
DELETE FROM meta WHERE key IN ('checkpoint_count', 'checkpoint_utime', 'checkpoint_last_frame_id');
PRAGMA user_version = 2;
)sql", ctx));
  return Status::ok();
}

// Schema 2 -> 3: pose rows carry a CRC-32 of their values (blob_codec.hpp,
// pose_record_checksum). Rows written before have none (NULL): readers cannot check them and
// `inspect` says so; their values are not guessed at. Where those rows end is recorded (meta
// pose_checksums_from_frame), so that a NULL checksum in a later row is damage, not history.
Status migrate_2_to_3(sql::Database& db) {
  return db.exec(R"sql(
ALTER TABLE poses ADD COLUMN checksum INTEGER;
INSERT OR REPLACE INTO meta (key, value)
  SELECT 'pose_checksums_from_frame', COALESCE(MAX(frame_id), 0) + 1 FROM poses;
PRAGMA user_version = 3;
)sql", "migrating schema 2 to 3");
}

// Schema 3 -> 4: the poses stored with keyframes and checkpoints carry a CRC-32 of their row as
// pose rows do (scan_store_internal.hpp). The keyframes table is rebuilt so that the checksum
// sits before the images (a column after a big blob would be read through its overflow pages).
// Rows written before keep NULL: unchecked, not guessed at; where they end is recorded as for
// poses (meta keyframe_checksums_from_frame, checkpoint_checksums_from_id).
Status migrate_3_to_4(sql::Database& db) {
  const std::string ctx = "migrating schema 3 to 4";
  DF_RETURN_IF_ERROR(db.exec("ALTER TABLE keyframes RENAME TO keyframes_v3;", ctx));
  DF_RETURN_IF_ERROR(db.exec(keyframes_table(/*with_checksum=*/true), ctx));
  return db.exec(R"sql(
INSERT INTO keyframes (frame_id, utime, sensor_serial, width, height, fx, fy, cx, cy, T_world_cam,
                       checksum, depth, color)
SELECT frame_id, utime, sensor_serial, width, height, fx, fy, cx, cy, T_world_cam, NULL, depth,
       color
FROM keyframes_v3;
DROP TABLE keyframes_v3;
ALTER TABLE checkpoints ADD COLUMN checksum INTEGER;
INSERT OR REPLACE INTO meta (key, value)
  SELECT 'keyframe_checksums_from_frame', COALESCE(MAX(frame_id), 0) + 1 FROM keyframes;
INSERT OR REPLACE INTO meta (key, value)
  SELECT 'checkpoint_checksums_from_id', COALESCE(MAX(id), 0) + 1 FROM checkpoints;
PRAGMA user_version = 4;
)sql", ctx);
}

// Schema 4 -> 5: the frame redo log. Every fused frame's pose, depth and colour are appended at
// least every second (a commit of a few frames' compressed images), so that durability costs a
// frame's bytes instead of rewriting every chunk in view; full checkpoints come less often and
// delete the records they cover. The checksum sits before the images (see migrate_3_to_4).
Status migrate_4_to_5(sql::Database& db) {
  return db.exec(R"sql(
CREATE TABLE frame_log (
  frame_id INTEGER PRIMARY KEY,
  utime INTEGER NOT NULL,
  T_world_cam BLOB NOT NULL,
  registered INTEGER NOT NULL,
  fitness REAL NOT NULL,
  rmse_m REAL NOT NULL,
  correspondences INTEGER NOT NULL,
  width INTEGER NOT NULL,
  height INTEGER NOT NULL,
  fx REAL NOT NULL,
  fy REAL NOT NULL,
  cx REAL NOT NULL,
  cy REAL NOT NULL,
  checksum INTEGER NOT NULL,
  depth BLOB NOT NULL,
  color BLOB
);
PRAGMA user_version = 5;
)sql", "migrating schema 4 to 5");
}

// Schema 5 -> 6: the pose graph and the map's deformation (docs/checkpoint-format.md, "The pose
// graph"). graph_keyframes holds each keyframe of the graph once, with the odometry edge that
// joins it to the one before and its cloud (append-only: neither changes once made); the one row
// of `graph` holds what a correction rewrites (the keyframes' poses, the loop edges, the graph's
// version, the deformation's history), written by every checkpoint. Chunks carry the version of
// the graph their points are in, and a CRC-32 of their row; the chunk tables are rebuilt so that
// both sit before the blob. Rows written before keep NULL (unchecked, version 0); where they end
// is recorded as for the other checksums (meta chunk_checksums_from_checkpoint).
Status migrate_5_to_6(sql::Database& db) {
  const std::string ctx = "migrating schema 5 to 6";
  for (const auto& [table, owner] : {std::pair<const char*, const char*>{"chunks", "checkpoint_id"},
                                     {"chunk_staging", "staged_utime"}}) {
    const std::string old = std::string(table) + "_v5";
    DF_RETURN_IF_ERROR(
        db.exec(std::string("ALTER TABLE ") + table + " RENAME TO " + old + ";", ctx));
    DF_RETURN_IF_ERROR(db.exec(chunk_table(table, owner, /*with_version=*/true), ctx));
    const std::string columns =
        std::string("x, y, z, point_count, min_x, min_y, min_z, max_x, max_y, max_z, "
                    "last_touched_frame, ") +
        owner + ", data";
    DF_RETURN_IF_ERROR(db.exec(std::string("INSERT INTO ") + table + " (" + columns + ") SELECT " +
                                   columns + " FROM " + old + "; DROP TABLE " + old + ";",
                               ctx));
  }
  return db.exec(R"sql(
CREATE TABLE graph_keyframes (
  keyframe INTEGER PRIMARY KEY,
  frame_id INTEGER NOT NULL,
  utime INTEGER NOT NULL,
  checksum INTEGER NOT NULL,
  odometry BLOB,
  cloud BLOB NOT NULL
);
CREATE TABLE graph (
  id INTEGER PRIMARY KEY CHECK (id = 1),
  checkpoint_id INTEGER NOT NULL,
  version INTEGER NOT NULL,
  keyframe_count INTEGER NOT NULL,
  checksum INTEGER NOT NULL,
  state BLOB NOT NULL
);
INSERT OR REPLACE INTO meta (key, value)
  SELECT 'chunk_checksums_from_checkpoint', COALESCE(MAX(id), 0) + 1 FROM checkpoints;
PRAGMA user_version = 6;
)sql", ctx);
}

// Schema 6 -> 7: a stored pose may be relative to a keyframe of the pose graph
// (`graph_keyframe`; NULL, as every row before, is the world frame), so that a correction moves
// the stored poses by moving the graph's keyframes instead of rewriting every row. The keyframes
// table is rebuilt so that the column sits before the images. The partial indexes find the rows
// a checkpoint has yet to anchor without reading the others.
Status migrate_6_to_7(sql::Database& db) {
  const std::string ctx = "migrating schema 6 to 7";
  DF_RETURN_IF_ERROR(db.exec("ALTER TABLE keyframes RENAME TO keyframes_v6;", ctx));
  DF_RETURN_IF_ERROR(db.exec(keyframes_table(/*with_checksum=*/true, /*with_anchor=*/true), ctx));
  return db.exec(R"sql(
INSERT INTO keyframes (frame_id, utime, sensor_serial, width, height, fx, fy, cx, cy, T_world_cam,
                       checksum, depth, color)
SELECT frame_id, utime, sensor_serial, width, height, fx, fy, cx, cy, T_world_cam, checksum, depth,
       color
FROM keyframes_v6;
DROP TABLE keyframes_v6;
ALTER TABLE poses ADD COLUMN graph_keyframe INTEGER;
CREATE INDEX poses_in_world ON poses (frame_id) WHERE graph_keyframe IS NULL;
CREATE INDEX keyframes_in_world ON keyframes (frame_id) WHERE graph_keyframe IS NULL;
PRAGMA user_version = 7;
)sql", ctx);
}

// Schema 7 -> 8: the points a loop closure moved into chunks that had not followed it yet (the
// map deformation's pending buffers; docs/checkpoint-format.md, `chunk_pending`). Before, every
// checkpoint brought those chunks up to date first, loading evicted ones: the fusion thread's time,
// hundreds of milliseconds while the deformation's sweep ran. The rows have the chunks' columns;
// a chunk may have points pending from several versions. Every row has a checksum (the column
// allows NULL as the chunk tables' do; a reader refuses a row without one).
Status migrate_7_to_8(sql::Database& db) {
  return db.exec(chunk_table("chunk_pending", "checkpoint_id", /*with_version=*/true,
                             "x, y, z, version") +
                     "PRAGMA user_version = 8;",
                 "migrating schema 7 to 8");
}

}  // namespace

Status create_current(sql::Database& db) {
  const std::string ctx = "creating the scan schema";
  DF_RETURN_IF_ERROR(db.exec(kCreateV2, ctx));
  DF_RETURN_IF_ERROR(db.exec(keyframes_table(/*with_checksum=*/false), ctx));
  DF_RETURN_IF_ERROR(db.exec(chunks_v2(), ctx));
  DF_RETURN_IF_ERROR(db.exec(added_in_v2(), ctx));
  DF_RETURN_IF_ERROR(migrate_2_to_3(db));
  DF_RETURN_IF_ERROR(migrate_3_to_4(db));
  DF_RETURN_IF_ERROR(migrate_4_to_5(db));
  DF_RETURN_IF_ERROR(migrate_5_to_6(db));
  DF_RETURN_IF_ERROR(migrate_6_to_7(db));
  DF_RETURN_IF_ERROR(migrate_7_to_8(db));
  DF_RETURN_IF_ERROR(db.exec("PRAGMA application_id = " + std::to_string(kApplicationId) + ";", ctx));
  DF_RETURN_IF_ERROR(db.exec("PRAGMA user_version = " + std::to_string(kSchemaVersion) + ";", ctx));
  return Status::ok();
}

Status migrate(sql::Database& db, int from_version) {
  static_assert(kSchemaVersion == 8, "add the migration step to the new version here");
  int v = from_version;
  if (v == 1) {
    DF_RETURN_IF_ERROR(migrate_1_to_2(db));
    v = 2;
  }
  if (v == 2) {
    DF_RETURN_IF_ERROR(migrate_2_to_3(db));
    v = 3;
  }
  if (v == 3) {
    DF_RETURN_IF_ERROR(migrate_3_to_4(db));
    v = 4;
  }
  if (v == 4) {
    DF_RETURN_IF_ERROR(migrate_4_to_5(db));
    v = 5;
  }
  if (v == 5) {
    DF_RETURN_IF_ERROR(migrate_5_to_6(db));
    v = 6;
  }
  if (v == 6) {
    DF_RETURN_IF_ERROR(migrate_6_to_7(db));
    v = 7;
  }
  if (v == 7) {
    DF_RETURN_IF_ERROR(migrate_7_to_8(db));
    v = 8;
  }
  if (v != kSchemaVersion)
    return unsupported(db.path() + ": no migration from schema version " +
                       std::to_string(from_version));
  return Status::ok();
}

}  // namespace depthfuse::store::schema
