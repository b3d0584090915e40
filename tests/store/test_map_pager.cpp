// MapPager on synthetic maps: memory stays within the budget while the camera walks far, every
// evicted chunk comes back bit for bit when the camera returns, nothing is ever lost; recently
// seen chunks give way only when the old ones do not make room; prepare() loads exactly the chunks
// a frame's depth can touch.
#include <gtest/gtest.h>

#include <map>

#include "depthfuse/store/map_pager.hpp"
#include "depthfuse/store/scan_store.hpp"
#include "store_test_util.hpp"

using namespace depthfuse;
using namespace depthfuse::store;
using test::bit_equal;
using test::ChunkContents;
using test::make_points;
using test::TempDir;

namespace {

// A walk along x, 0.25 m per frame: each frame "fuses" by growing the chunks within 2 m of the
// camera, as fusion would.
struct Walk {
  PointMap map{0.5};
  ChunkContents reference;  // what every chunk should hold
  uint32_t frame = 0;

  Eigen::Vector3f camera(int step) const { return Eigen::Vector3f(0.25f * step, 0.1f, 1.0f); }

  void fuse_at(const Eigen::Vector3f& cam) {
    ++frame;
    const ChunkKey c = map.key_for(cam);
    for (int dx = -4; dx <= 4; ++dx) {
      for (int dz = -2; dz <= 0; ++dz) {
        const ChunkKey k{c.x + dx, c.y, c.z + dz};
        Chunk& ch = map.get_or_create(k);
        const PointArrays add = make_points(k, frame, 5);
        ch.points_for_write().append(add);
        ch.last_touched_frame = ch.last_seen_frame = frame;
        ch.dirty = true;
        reference[k].append(add);
      }
    }
  }
};

}  // namespace

TEST(MapPager, BoundedWalkAndReturnIsLossless) {
  TempDir dir;
  auto store = ScanStore::open(dir.file("scan.db"), OpenMode::kCreate);
  ASSERT_TRUE(store);
  MapPagerConfig config;
  config.memory_budget_mib = 0.5;
  config.evict_distance_m = 0.5;
  config.min_age_frames = 4;
  ASSERT_TRUE(MapPager::validate(config));
  MapPager pager(config, store->get());
  Walk walk;
  const size_t budget = static_cast<size_t>(config.memory_budget_mib * 1024 * 1024);
  size_t max_resident = 0;
  const int steps = 400;  // 100 m out, then back
  for (int i = 0; i <= 2 * steps; ++i) {
    const Eigen::Vector3f cam = walk.camera(i <= steps ? i : 2 * steps - i);
    // Stands in for prepare(): everything this "frame" will touch lies within 2.3 m.
    ASSERT_TRUE(pager.load_around(&walk.map, cam, 2.3, walk.frame + 1)) << pager.stats().last_error;
    walk.fuse_at(cam);
    ASSERT_TRUE(pager.update(&walk.map, cam, walk.frame)) << pager.stats().last_error;
    size_t resident = 0;
    walk.map.for_each_chunk([&](const ChunkKey&, const Chunk& c) { resident += MapPager::chunk_bytes(c); });
    EXPECT_EQ(resident, pager.stats().resident_bytes);
    max_resident = std::max(max_resident, resident);
    EXPECT_LE(resident, budget) << "step " << i;
    EXPECT_EQ(pager.stats().unevictable_bytes, 0u) << "step " << i;
    // Every chunk is either in memory or in the evicted index, never both, never neither.
    for (const auto& [k, points] : walk.reference)
      ASSERT_NE(walk.map.find(k) != nullptr, pager.is_evicted(k)) << to_string(k) << " at step " << i;
  }
  const PagerStats& s = pager.stats();
  EXPECT_GT(s.total_evicted, 100u);
  EXPECT_GT(s.total_loaded, 100u);
  EXPECT_EQ(s.load_collisions, 0u);
  std::printf("budget %zu B, max resident %zu B, %zu chunks in total, evicted %llu, loaded %llu\n", budget,
              max_resident, walk.reference.size(), static_cast<unsigned long long>(s.total_evicted),
              static_cast<unsigned long long>(s.total_loaded));
  // Back at the start: the chunks there came back exactly as they were written.
  for (const auto& [k, points] : walk.reference) {
    if (const Chunk* c = walk.map.find(k)) {
      EXPECT_TRUE(bit_equal(c->points(), points)) << to_string(k);
    }
  }
  // And every evicted chunk in the store is exactly the reference.
  for (const ChunkKey& k : pager.evicted()) {
    auto c = (*store)->read_chunk(k, /*include_staged=*/true);
    ASSERT_TRUE(c) << c.status().to_string();
    EXPECT_TRUE(bit_equal(c->chunk.points(), walk.reference.at(k))) << to_string(k);
  }
}

namespace {

// 41 chunks in a row, x = -20 .. 20, 50 points each, around a camera in chunk 0 at frame 100:
// x 11..20 were seen 5 frames ago, x = 15 by frame 100 itself, the rest at frame 50.
void fill_row(PointMap* map) {
  for (int x = -20; x <= 20; ++x) {
    Chunk& c = map->get_or_create({x, 0, 0});
    c.points_for_write() = make_points({x, 0, 0}, 1, 50);
    c.last_touched_frame = c.last_seen_frame = x == 15 ? 100 : x > 10 ? 95 : 50;
    c.dirty = true;
  }
}

MapPagerConfig row_config(double budget_mib) {
  MapPagerConfig config;
  config.memory_budget_mib = budget_mib;
  config.evict_distance_m = 2.0;  // keys -4 .. 4 are near the camera
  config.min_age_frames = 10;
  return config;
}

const Eigen::Vector3f kRowCamera(0.25f, 0.25f, 0.25f);

}  // namespace

TEST(MapPager, RecentlySeenChunksStayWhileTheOldOnesMakeRoom) {
  TempDir dir;
  auto store = ScanStore::open(dir.file("scan.db"), OpenMode::kCreate);
  ASSERT_TRUE(store);
  PointMap map(0.5);
  fill_row(&map);
  const size_t chunk = MapPager::chunk_bytes(*map.find({0, 0, 0}));
  // Room for 25 chunks: evicting the 22 old far ones (down to 85 %, 21 chunks) suffices.
  MapPager pager(row_config(25.0 * chunk / (1024.0 * 1024.0)), store->get());
  ASSERT_TRUE(pager.update(&map, kRowCamera, 100));
  EXPECT_LE(pager.stats().resident_bytes, static_cast<size_t>(0.85 * 25 * chunk) + 1);
  EXPECT_EQ(pager.stats().unevictable_bytes, 0u);
  EXPECT_EQ(pager.stats().total_evicted, 20u);
  EXPECT_EQ(pager.stats().total_evicted_recent, 0u);
  for (int x = -4; x <= 20; ++x) {
    if (x > 4 && x <= 10) continue;
    EXPECT_NE(map.find({x, 0, 0}), nullptr) << "near or recent chunk " << x << " was evicted";
  }
}

// What else the map's budget holds (the pose graph, the deformation's history: set_other_bytes)
// takes the room of chunks. Room for 25 chunks, ten of them taken: the 22 old far chunks go, and
// since that leaves 19 + 10, four recently seen ones too, down to the budget (without the other
// bytes the old ones alone sufficed: the test above).
TEST(MapPager, OtherBytesInTheBudgetEvictChunksToMakeRoom) {
  TempDir dir;
  auto store = ScanStore::open(dir.file("scan.db"), OpenMode::kCreate);
  ASSERT_TRUE(store);
  PointMap map(0.5);
  fill_row(&map);
  const size_t chunk = MapPager::chunk_bytes(*map.find({0, 0, 0}));
  const size_t chunks_before = map.chunk_count();
  MapPager pager(row_config(25.0 * chunk / (1024.0 * 1024.0)), store->get());
  pager.set_other_bytes(10 * chunk);
  ASSERT_TRUE(pager.update(&map, kRowCamera, 100));
  EXPECT_EQ(pager.stats().other_bytes, 10 * chunk);
  EXPECT_LE(pager.stats().resident_bytes, 25 * chunk);
  EXPECT_EQ(pager.stats().total_evicted, 26u) << "of " << chunks_before;
  EXPECT_EQ(pager.stats().total_evicted_recent, 4u);
}

TEST(MapPager, BudgetHoldsOverRecentChunksButNotOverThisFramesOrNearOnes) {
  TempDir dir;
  auto store = ScanStore::open(dir.file("scan.db"), OpenMode::kCreate);
  ASSERT_TRUE(store);
  MapPager pager(row_config(0.01), store->get());  // far below the near chunks alone
  PointMap map(0.5);
  fill_row(&map);
  ASSERT_TRUE(pager.update(&map, kRowCamera, 100));
  // Kept: within 2 m of the camera (keys -4..4) and what frame 100 itself observed (15).
  map.for_each_chunk([&](const ChunkKey& k, const Chunk&) {
    EXPECT_TRUE((k.x >= -4 && k.x <= 4) || k.x == 15) << to_string(k);
  });
  EXPECT_EQ(map.chunk_count(), 10u);
  EXPECT_GT(pager.stats().unevictable_bytes, 0u);
  EXPECT_EQ(pager.stats().total_evicted_recent, 9u);  // 11 .. 20 but 15
  // load_around brings back exactly the evicted chunks within the radius: from x = 3.25 m within
  // 1.5 m is x in [1.75, 4.75] m, keys 3 .. 9, of which 5 .. 9 were evicted.
  const uint64_t loaded_before = pager.stats().total_loaded;
  ASSERT_TRUE(pager.load_around(&map, Eigen::Vector3f(3.25f, 0.25f, 0.25f), 1.5, 101));
  EXPECT_EQ(pager.stats().total_loaded - loaded_before, 5u);
  for (int x = 3; x <= 9; ++x) EXPECT_NE(map.find({x, 0, 0}), nullptr) << x;
  EXPECT_EQ(map.find({10, 0, 0}), nullptr);
  // Loaded for frame 101 (as prepare() does) counts as used by it: the update after frame 101
  // keeps them, over budget as it is.
  ASSERT_TRUE(pager.update(&map, kRowCamera, 101));
  for (int x = 5; x <= 9; ++x) EXPECT_NE(map.find({x, 0, 0}), nullptr) << x;
  // A frame later they are merely recent, and the budget wins.
  ASSERT_TRUE(pager.update(&map, kRowCamera, 102));
  for (int x = 5; x <= 9; ++x) EXPECT_EQ(map.find({x, 0, 0}), nullptr) << x;
  EXPECT_TRUE(pager.is_evicted({7, 0, 0}));
}

TEST(MapPager, PrepareLoadsTheChunksTheFrameCanTouch) {
  TempDir dir;
  auto store = ScanStore::open(dir.file("scan.db"), OpenMode::kCreate);
  ASSERT_TRUE(store);
  MapPagerConfig config;
  config.load_margin_m = 0.3;
  MapPager pager(config, store->get());
  PointMap map(0.5);
  // Everything in a 12 x 12 x 4 m block is evicted.
  for (int x = -4; x < 20; ++x)
    for (int y = -12; y < 12; ++y)
      for (int z = 0; z < 8; ++z) pager.mark_evicted({x, y, z});
  // Store them so that loading finds them (the content does not matter here).
  std::vector<Chunk> chunks;
  std::vector<std::pair<ChunkKey, const Chunk*>> batch;
  chunks.reserve(pager.evicted().size());
  for (const ChunkKey& k : pager.evicted()) {
    chunks.emplace_back();
    chunks.back().points_for_write() = make_points(k, 1, 2);
    batch.emplace_back(k, &chunks.back());
  }
  ASSERT_TRUE((*store)->stage_chunks(batch));
  // A camera at (0, 0, 1.5) looking along +x at a wall x = 6 m.
  const CameraIntrinsics K = test::small_camera();
  const Pose T = test::look_at(Eigen::Vector3d(0, 0, 1.5), Eigen::Vector3d(6, 0, 1.5));
  Frame f;
  f.intrinsics = K;
  f.depth = DepthImage(K.width, K.height);
  for (int v = 0; v < K.height; ++v)
    for (int u = 0; u < K.width; ++u) f.depth.at(u, v) = 6.0f;  // z = 6 m everywhere: the wall
  ASSERT_TRUE(pager.prepare(&map, f, T, 1)) << pager.stats().last_error;
  // Loaded: chunks touching the wall's visible patch and the last 10 % of the rays before it.
  const Eigen::Vector3f o(0, 0, 1.5f);
  size_t loaded = 0;
  map.for_each_chunk([&](const ChunkKey& k, const Chunk&) {
    ++loaded;
    const Eigen::Vector3f lo = map.chunk_origin_m(k);
    EXPECT_GE(lo.x() + 0.5f, 6.0f * 0.9f * 0.95f - 0.31f) << to_string(k);  // nothing near the camera
    EXPECT_LE(lo.x(), 6.3f) << to_string(k);
  });
  EXPECT_GT(loaded, 50u);
  // Every chunk holding a wall sample is resident.
  for (int v = 0; v < K.height; v += 3) {
    for (int u = 0; u < K.width; u += 3) {
      const Eigen::Vector3d p = T * Eigen::Vector3d((u - K.cx) / K.fx * 6.0, (v - K.cy) / K.fy * 6.0, 6.0);
      const ChunkKey k = map.key_for(p.cast<float>());
      if (k.z < 0 || k.z >= 8 || k.y < -12 || k.y >= 12) continue;
      EXPECT_NE(map.find(k), nullptr) << to_string(k);
    }
  }
  // Nothing left evicted that the frame can see, so a second call loads nothing.
  const uint64_t before = pager.stats().total_loaded;
  ASSERT_TRUE(pager.prepare(&map, f, T, 2));
  EXPECT_EQ(pager.stats().total_loaded, before);
}

TEST(MapPager, RejectsBadConfigs) {
  MapPagerConfig c;
  EXPECT_TRUE(MapPager::validate(c));
  c.memory_budget_mib = 0;
  EXPECT_FALSE(MapPager::validate(c));
  c = MapPagerConfig{};
  c.load_subsample_px = 0;
  EXPECT_FALSE(MapPager::validate(c));
  c = MapPagerConfig{};
  c.low_watermark_fraction = 1.5;
  EXPECT_FALSE(MapPager::validate(c));
}

// Fusion may create a chunk at an evicted key that prepare() did not load (a pose correction
// larger than the load margin): update() brings the stored points back into it before anything
// can write the new chunk over the stored one.
TEST(MapPager, AChunkCreatedOverAnEvictedOneKeepsTheStoredPoints) {
  TempDir dir;
  auto store = ScanStore::open(dir.file("scan.db"), OpenMode::kCreate);
  ASSERT_TRUE(store);
  MapPager pager(row_config(0.001), store->get());
  PointMap map(0.5);
  const ChunkKey k{12, 0, 0};  // 6 m from the camera
  const PointArrays stored = make_points(k, 1, 40), fresh = make_points(k, 2, 7);
  Chunk& c = map.get_or_create(k);
  c.points_for_write() = stored;
  c.last_touched_frame = c.last_seen_frame = 10;
  c.dirty = true;
  ASSERT_TRUE(pager.update(&map, kRowCamera, 100));
  ASSERT_EQ(map.find(k), nullptr);
  ASSERT_TRUE(pager.is_evicted(k));
  // Frame 101 fuses new points there without the chunk having been loaded.
  Chunk& created = map.get_or_create(k);
  created.points_for_write() = fresh;
  created.last_touched_frame = created.last_seen_frame = 101;
  created.dirty = true;
  ASSERT_TRUE(pager.update(&map, kRowCamera, 101)) << pager.stats().last_error;
  EXPECT_EQ(pager.stats().load_collisions, 1u);
  EXPECT_FALSE(pager.is_evicted(k));
  PointArrays both = stored;
  both.append(fresh);
  ASSERT_NE(map.find(k), nullptr);
  EXPECT_TRUE(bit_equal(map.find(k)->points(), both));
  // Evicted again, the file holds both sets.
  ASSERT_TRUE(pager.update(&map, kRowCamera, 200));
  ASSERT_EQ(map.find(k), nullptr);
  auto in_file = (*store)->read_chunk(k, /*include_staged=*/true);
  ASSERT_TRUE(in_file) << in_file.status().to_string();
  EXPECT_TRUE(bit_equal(in_file->chunk.points(), both));
}

// A loop closure while a chunk was evicted: fusion (or the map's deformation) made a new chunk at
// its key at the new version. The stored points follow the corrections (here: a hook standing for
// MapDeformation::update, moving them 1 cm) before the new ones join them, and the pager keeps
// the evicted chunks' oldest version for the deformation's history.
TEST(MapPager, AChunkLoadedOverANewerOneIsBroughtUpToDateFirst) {
  TempDir dir;
  auto store = ScanStore::open(dir.file("scan.db"), OpenMode::kCreate);
  ASSERT_TRUE(store);
  MapPager pager(row_config(0.001), store->get());
  size_t brought = 0;
  pager.set_bring_up_to_date([&](PointMap* m, const ChunkKey& key) {
    Chunk* c = m->find(key);
    ASSERT_NE(c, nullptr);
    for (size_t i = 0; i < c->points().size(); ++i) c->points_for_write().position_m[i].x() += 0.01f;
    c->version = m->version();
    ++brought;
  });
  PointMap map(0.5);
  const ChunkKey k{12, 0, 0};  // 6 m from the camera
  const PointArrays stored = make_points(k, 1, 40), fresh = make_points(k, 2, 7);
  Chunk& c = map.get_or_create(k);
  c.points_for_write() = stored;
  c.last_touched_frame = c.last_seen_frame = 10;
  c.dirty = true;
  ASSERT_TRUE(pager.update(&map, kRowCamera, 100));
  ASSERT_TRUE(pager.is_evicted(k));
  EXPECT_EQ(pager.oldest_evicted_version(), std::optional<uint32_t>(0));
  map.set_version(1);  // a correction
  Chunk& created = map.get_or_create(k);
  EXPECT_EQ(created.version, 1u);
  created.points_for_write() = fresh;
  created.last_touched_frame = created.last_seen_frame = 101;
  created.dirty = true;
  ASSERT_TRUE(pager.update(&map, kRowCamera, 101)) << pager.stats().last_error;
  EXPECT_EQ(brought, 1u);
  EXPECT_EQ(pager.oldest_evicted_version(), std::nullopt);
  PointArrays both = stored;
  for (size_t i = 0; i < both.size(); ++i) both.position_m[i].x() += 0.01f;
  both.append(fresh);
  ASSERT_NE(map.find(k), nullptr);
  EXPECT_EQ(map.find(k)->version, 1u);
  EXPECT_TRUE(bit_equal(map.find(k)->points(), both));
  // Evicted again at version 1: the file keeps it.
  ASSERT_TRUE(pager.update(&map, kRowCamera, 200));
  EXPECT_EQ(pager.oldest_evicted_version(), std::optional<uint32_t>(1));
  auto in_file = (*store)->read_chunk(k, /*include_staged=*/true);
  ASSERT_TRUE(in_file) << in_file.status().to_string();
  EXPECT_EQ(in_file->chunk.version, 1u);
}

namespace {

// A changed chunk of 50 points at `key`, last seen at `frame`, never staged.
void add_changed_chunk(PointMap* map, const ChunkKey& key, uint32_t frame) {
  Chunk& c = map->get_or_create(key);
  c.points_for_write() = make_points(key, frame, 50);
  c.last_touched_frame = c.last_seen_frame = frame;
  c.dirty = true;
}

// The row of chunks with a budget of 25 of them: frame 100 stages the 20 old far ones, and one of
// those, `staged`, is loaded back at frame 30 and changed (by a frame after the next snapshot).
struct StagedRow {
  TempDir dir;
  std::unique_ptr<ScanStore> store;
  PointMap map{0.5};
  size_t chunk = 0;
  std::unique_ptr<MapPager> pager;
  int waits = 0;  // calls of wait_for_checkpoint
  const ChunkKey staged{-20, 0, 0};

  void SetUp() {
    auto opened = ScanStore::open(dir.file("scan.db"), OpenMode::kCreate);
    ASSERT_TRUE(opened);
    store = std::move(*opened);
    fill_row(&map);
    chunk = MapPager::chunk_bytes(*map.find({0, 0, 0}));
    pager = std::make_unique<MapPager>(row_config(25.0 * chunk / (1024.0 * 1024.0)), store.get());
    pager->set_checkpoint_hooks([] { return false; }, [this] { ++waits; });
    ASSERT_TRUE(pager->update(&map, kRowCamera, 100));
    ASSERT_TRUE(pager->is_evicted(staged));
    ASSERT_TRUE(pager->load_chunks(&map, {staged}, 30));  // the least recently used of all
    Chunk& again = map.get_or_create(staged);
    again.points_for_write().append(make_points(staged, 61, 10));
    again.dirty = true;
  }
};

}  // namespace

// A checkpoint written in the background promotes the chunks staged before its snapshot. Staging
// such a chunk again while it is in flight would replace the copy the checkpoint is to promote
// (and lose what it held if the new copy is of later frames): within the budget it waits for a
// later frame, other changed chunks go as usual and nothing waits for the checkpoint. Over the
// budget it goes, after the checkpoint is done.
TEST(MapPager, AChunkOfTheCheckpointInFlightIsNotStagedAgainUntilItIsDone) {
  StagedRow r;
  ASSERT_NO_FATAL_FAILURE(r.SetUp());
  add_changed_chunk(&r.map, {-30, 0, 0}, 40);
  add_changed_chunk(&r.map, {-31, 0, 0}, 40);

  r.pager->checkpoint_snapshot();
  ASSERT_TRUE(r.pager->update(&r.map, kRowCamera, 101));  // above the low watermark, within the budget
  EXPECT_NE(r.map.find(r.staged), nullptr) << "staged again while the checkpoint was in flight";
  EXPECT_TRUE(r.pager->is_evicted({-30, 0, 0}));
  EXPECT_EQ(r.waits, 0);
  auto in_file = r.store->read_chunk(r.staged, /*include_staged=*/true);
  ASSERT_TRUE(in_file);
  EXPECT_EQ(in_file->chunk.points().size(), 50u) << "the staged copy was replaced";

  r.pager->set_other_bytes(20 * r.chunk);  // over the budget: it must go, once the checkpoint is done
  ASSERT_TRUE(r.pager->update(&r.map, kRowCamera, 102));
  EXPECT_TRUE(r.pager->is_evicted(r.staged));
  EXPECT_EQ(r.waits, 1);
  r.pager->checkpoint_done(true);
  in_file = r.store->read_chunk(r.staged, /*include_staged=*/true);
  ASSERT_TRUE(in_file);
  EXPECT_EQ(in_file->chunk.points().size(), 60u);
}

// Over the budget, a changed chunk of the checkpoint in flight goes last even when it is the least
// recently used: staging it waits for the checkpoint's encoding and transaction, half a second on
// a long scan, while the other candidates go at once.
TEST(MapPager, OverTheBudgetAChunkOfTheCheckpointInFlightGoesLast) {
  StagedRow r;
  ASSERT_NO_FATAL_FAILURE(r.SetUp());
  add_changed_chunk(&r.map, {-30, 0, 0}, 40);

  r.pager->checkpoint_snapshot();
  r.pager->set_other_bytes(3 * r.chunk);  // a chunk or so over the budget
  ASSERT_TRUE(r.pager->update(&r.map, kRowCamera, 101));
  EXPECT_EQ(r.waits, 0) << "waited for the checkpoint though other chunks could go";
  EXPECT_NE(r.map.find(r.staged), nullptr);
  EXPECT_TRUE(r.pager->is_evicted({-30, 0, 0}));
  EXPECT_LE(r.pager->stats().resident_bytes, static_cast<size_t>(25 * r.chunk));
}
