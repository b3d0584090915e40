// Helpers for the scan store tests: temporary directories, deterministic point data, bitwise
// comparison, and a small analytic scene (a corridor with boxes) rendered exactly.
#pragma once

#include <gtest/gtest.h>
#include <sqlite3.h>
#include <sys/wait.h>
#include <unistd.h>

#include <cmath>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <map>
#include <fstream>
#include <random>
#include <string>
#include <tuple>
#include <vector>

#include "depthfuse/point_arrays.hpp"
#include "depthfuse/point_map.hpp"
#include "depthfuse/types.hpp"

namespace depthfuse::store::test {

// A fresh directory for one test's files, removed at the end unless the test failed (what it left
// is then worth looking at) or DEPTHFUSE_KEEP_TEST_FILES is set. The one temporary directory of the
// store and fusion_store tests.
class TempDir {
 public:
  explicit TempDir(const std::string& tag = "store") {
    std::string tmpl =
        (std::filesystem::temp_directory_path() / ("depthfuse-" + tag + "-XXXXXX")).string();
    if (!mkdtemp(tmpl.data())) std::abort();
    path_ = tmpl;
  }
  ~TempDir() {
    if (std::getenv("DEPTHFUSE_KEEP_TEST_FILES") || ::testing::Test::HasFailure()) {
      std::fprintf(stderr, "kept %s\n", path_.c_str());
      return;
    }
    std::error_code ec;
    std::filesystem::remove_all(path_, ec);
  }
  TempDir(const TempDir&) = delete;
  TempDir& operator=(const TempDir&) = delete;
  std::string file(const std::string& name) const { return path_ + "/" + name; }
  const std::string& path() const { return path_; }

 private:
  std::string path_;
};

// Deterministic points for a chunk: content depends on (key, version) only.
inline PointArrays make_points(const ChunkKey& key, uint32_t version, size_t n, double chunk_m = 0.5) {
  std::mt19937 rng(static_cast<uint32_t>(key.x * 73856093 ^ key.y * 19349663 ^ key.z * 83492791) ^
                   (version * 2654435761u));
  std::uniform_real_distribution<float> u(0.0f, static_cast<float>(chunk_m));
  std::uniform_real_distribution<float> s(-1.0f, 1.0f);
  PointArrays a;
  for (size_t i = 0; i < n; ++i) {
    PointRecord p;
    p.position_m = Eigen::Vector3f(key.x * chunk_m + u(rng), key.y * chunk_m + u(rng), key.z * chunk_m + u(rng));
    p.normal = Eigen::Vector3f(s(rng), s(rng), s(rng)).normalized();
    for (float& f : p.information) f = s(rng) * 1e6f;
    p.rgb[0] = static_cast<uint8_t>(rng());
    p.rgb[1] = static_cast<uint8_t>(rng());
    p.rgb[2] = static_cast<uint8_t>(rng());
    p.merges = static_cast<uint16_t>(rng());
    p.violations = static_cast<uint16_t>(rng());
    p.last_frame = version;
    a.push_back(p);
  }
  return a;
}

template <typename T>
bool same_bits(const std::vector<T>& a, const std::vector<T>& b) {
  return a.size() == b.size() && (a.empty() || std::memcmp(a.data(), b.data(), a.size() * sizeof(T)) == 0);
}

// Bitwise equality of both arrays (float == would call -0 == 0 equal and NaN != NaN).
inline bool bit_equal(const PointArrays& a, const PointArrays& b) {
  return same_bits(a.position_m, b.position_m) && same_bits(a.state, b.state);
}

// Chunk contents by key, in a fixed order, for comparing two clouds chunk by chunk.
struct KeyLess {
  bool operator()(const ChunkKey& a, const ChunkKey& b) const {
    return std::tie(a.x, a.y, a.z) < std::tie(b.x, b.y, b.z);
  }
};
using ChunkContents = std::map<ChunkKey, PointArrays, KeyLess>;

inline size_t point_total(const ChunkContents& c) {
  size_t n = 0;
  for (const auto& [k, a] : c) n += a.size();
  return n;
}

// The same chunks holding the same bytes.
inline void expect_same_cloud(const ChunkContents& got, const ChunkContents& want) {
  EXPECT_EQ(got.size(), want.size());
  size_t different = 0, missing = 0;
  for (const auto& [k, a] : want) {
    auto it = got.find(k);
    if (it == got.end()) ++missing;
    else if (!bit_equal(it->second, a)) ++different;
  }
  EXPECT_EQ(missing, 0u);
  EXPECT_EQ(different, 0u) << "of " << want.size() << " chunks (" << point_total(want) << " points)";
}

inline Pose look_at(const Eigen::Vector3d& eye, const Eigen::Vector3d& target) {
  const Eigen::Vector3d z = (target - eye).normalized();
  Eigen::Vector3d x = z.cross(Eigen::Vector3d::UnitZ());
  if (x.norm() < 1e-6) x = z.unitOrthogonal();
  x.normalize();
  const Eigen::Vector3d y = z.cross(x);
  Pose T = Pose::Identity();
  T.linear().col(0) = x;
  T.linear().col(1) = y;
  T.linear().col(2) = z;
  T.translation() = eye;
  return T;
}

// A corridor along +x: floor z = 0, ceiling z = 2.5, walls y = -1.5 and y = 1.5, closed at
// x = -1 and x = length, with boxes on both walls every 1.3 m so that ICP is constrained along x.
struct Corridor {
  double length_m = 30.0;

  struct Box { Eigen::Vector3d lo, hi; };
  std::vector<Box> boxes() const {
    std::vector<Box> out;
    for (double x = 0.3; x + 0.4 < length_m; x += 1.3) {
      const double h = 0.4 + 0.3 * std::fmod(x * 1.7, 1.0);
      out.push_back({{x, -1.5, 0.0}, {x + 0.4, -1.1, h}});
      out.push_back({{x + 0.6, 1.1, 0.0}, {x + 1.0, 1.5, h + 0.5}});
    }
    return out;
  }

  // Ray parameter of the first hit, or +inf.
  double cast(const Eigen::Vector3d& o, const Eigen::Vector3d& d, const std::vector<Box>& boxes) const {
    double best = INFINITY;
    // Inside of the outer box.
    const Eigen::Vector3d lo(-1.0, -1.5, 0.0), hi(length_m, 1.5, 2.5);
    for (int a = 0; a < 3; ++a) {
      if (std::abs(d[a]) < 1e-12) continue;
      for (double plane : {lo[a], hi[a]}) {
        const double s = (plane - o[a]) / d[a];
        if (s > 1e-6 && s < best) best = s;
      }
    }
    for (const Box& b : boxes) {  // slab test, outside hits only
      double t0 = 0, t1 = best;
      bool hit = true;
      for (int a = 0; a < 3 && hit; ++a) {
        if (std::abs(d[a]) < 1e-12) {
          hit = o[a] >= b.lo[a] && o[a] <= b.hi[a];
          continue;
        }
        double ta = (b.lo[a] - o[a]) / d[a], tb = (b.hi[a] - o[a]) / d[a];
        if (ta > tb) std::swap(ta, tb);
        t0 = std::max(t0, ta);
        t1 = std::min(t1, tb);
        hit = t0 <= t1;
      }
      if (hit && t0 > 1e-6 && t0 < best) best = t0;
    }
    return best;
  }

  Frame render(const Pose& T_world_cam, const CameraIntrinsics& K, uint32_t sequence) const {
    Frame f;
    f.intrinsics = K;
    f.sequence = sequence;
    f.utime = 1700000000000000LL + static_cast<int64_t>(sequence) * 33333;
    f.sensor_serial = "test-corridor";
    f.depth = DepthImage(K.width, K.height);
    f.color.width = K.width;
    f.color.height = K.height;
    f.color.rgb.assign(static_cast<size_t>(K.width) * K.height * 3, 0);
    const auto bx = boxes();
    const Eigen::Vector3d o = T_world_cam.translation();
    for (int v = 0; v < K.height; ++v) {
      for (int u = 0; u < K.width; ++u) {
        const Eigen::Vector3d ray_w =
            T_world_cam.linear() * Eigen::Vector3d((u - K.cx) / K.fx, (v - K.cy) / K.fy, 1.0);
        const double s = cast(o, ray_w, bx);
        if (!std::isfinite(s) || s > 4.4) continue;
        f.depth.at(u, v) = static_cast<float>(s);
        const Eigen::Vector3d p = o + s * ray_w;
        uint8_t* c = &f.color.rgb[(static_cast<size_t>(v) * K.width + u) * 3];
        c[0] = static_cast<uint8_t>(128 + 100 * std::sin(p.x() * 3.0));
        c[1] = static_cast<uint8_t>(128 + 100 * std::sin(p.y() * 5.0));
        c[2] = static_cast<uint8_t>(128 + 100 * std::sin(p.z() * 7.0));
      }
    }
    f.T_world_cam_hint = T_world_cam;
    return f;
  }

  // Walks to the far end and back, looking ahead with a slight sideways sway.
  Pose pose(int i, int frames) const {
    const double half = frames / 2.0;
    const double s = i < half ? i / half : (frames - i) / half;  // 0 -> 1 -> 0
    const double x = 0.5 + s * (length_m - 3.0);
    const bool back = i >= half;
    const Eigen::Vector3d eye(x, 0.3 * std::sin(i * 0.05), 1.3);
    const Eigen::Vector3d ahead = eye + Eigen::Vector3d(back ? -2.0 : 2.0, 0.8 * std::sin(i * 0.03), -0.4);
    return look_at(eye, ahead);
  }
};

inline CameraIntrinsics small_camera() {
  CameraIntrinsics K;
  K.width = 128;
  K.height = 106;
  K.fx = K.fy = 91.25;
  K.cx = 63.5;
  K.cy = 52.5;
  return K;
}

inline void flip_byte(const std::string& path, long offset) {
  std::fstream f(path, std::ios::in | std::ios::out | std::ios::binary);
  f.seekg(offset);
  char c = 0;
  f.read(&c, 1);
  c = static_cast<char>(c ^ 0x5A);
  f.seekp(offset);
  f.write(&c, 1);
}

// A command line's exit code and its stdout and stderr together (the CLI tests).
struct Proc {
  int code = -1;
  std::string output;
};

inline Proc run(const std::string& cmd) {
  Proc r;
  FILE* p = popen((cmd + " 2>&1").c_str(), "r");
  if (!p) return r;
  char buf[4096];
  size_t n;
  while ((n = fread(buf, 1, sizeof(buf), p)) > 0) r.output.append(buf, n);
  const int status = pclose(p);
  r.code = WIFEXITED(status) ? WEXITSTATUS(status) : 128 + WTERMSIG(status);
  return r;
}

// Runs `sql` on the file at `path` as another program would (tests that alter or damage rows).
inline void exec_sql(const std::string& path, const std::string& sql) {
  sqlite3* db = nullptr;
  ASSERT_EQ(sqlite3_open(path.c_str(), &db), SQLITE_OK);
  char* err = nullptr;
  const int rc = sqlite3_exec(db, sql.c_str(), nullptr, nullptr, &err);
  EXPECT_EQ(rc, SQLITE_OK) << (err ? err : "");
  sqlite3_free(err);
  sqlite3_close(db);
}

// SQL that turns a file of the current schema into what schema 7 wrote: no pending points table.
inline std::string as_schema_7_sql() { return "DROP TABLE chunk_pending; PRAGMA user_version = 7;"; }

// SQL that turns a file of the current schema into what schema 6 wrote: every stored pose in the
// world frame, no graph_keyframe columns, user_version 6.
inline std::string as_schema_6_sql() {
  return as_schema_7_sql() + "DROP INDEX poses_in_world; DROP INDEX keyframes_in_world; "
         "ALTER TABLE poses DROP COLUMN graph_keyframe; "
         "ALTER TABLE keyframes DROP COLUMN graph_keyframe; PRAGMA user_version = 6;";
}

// SQL that turns a file of the current schema into what schema 5 wrote: chunk tables without the
// version and checksum columns, no pose graph tables, user_version 5.
inline std::string as_schema_5_sql() {
  std::string sql = as_schema_6_sql();
  for (const char* table : {"chunks", "chunk_staging"}) {
    const std::string owner = std::string(table) == "chunks" ? "checkpoint_id" : "staged_utime";
    const std::string t = table;
    sql += "CREATE TABLE " + t + "_v5 (x INTEGER NOT NULL, y INTEGER NOT NULL, z INTEGER NOT NULL, "
           "point_count INTEGER NOT NULL, min_x REAL, min_y REAL, min_z REAL, max_x REAL, max_y REAL, "
           "max_z REAL, last_touched_frame INTEGER NOT NULL, " + owner + " INTEGER NOT NULL, data BLOB "
           "NOT NULL, PRIMARY KEY (x, y, z)); INSERT INTO " + t + "_v5 SELECT x, y, z, point_count, "
           "min_x, min_y, min_z, max_x, max_y, max_z, last_touched_frame, " + owner + ", data FROM " + t +
           "; DROP TABLE " + t + "; ALTER TABLE " + t + "_v5 RENAME TO " + t + ";";
  }
  return sql + "DROP TABLE graph_keyframes; DROP TABLE graph; DELETE FROM meta WHERE key = "
               "'chunk_checksums_from_checkpoint'; PRAGMA user_version = 5;";
}

}  // namespace depthfuse::store::test
