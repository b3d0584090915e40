// MapPager on a synthetic map: memory stays within the budget while the camera walks far, every
// evicted chunk comes back bit for bit when the camera returns, nothing is ever lost.
#include <gtest/gtest.h>

#include <map>

#include "depthfuse/store/map_pager.hpp"
#include "depthfuse/store/scan_store.hpp"
#include "store_test_util.hpp"

using namespace depthfuse;
using namespace depthfuse::store;
using test::bit_equal;
using test::make_points;
using test::TempDir;

namespace {

struct KeyLess {
  bool operator()(const ChunkKey& a, const ChunkKey& b) const {
    return std::tie(a.x, a.y, a.z) < std::tie(b.x, b.y, b.z);
  }
};

// A walk along x, 0.25 m per frame: each frame "fuses" by creating or growing the chunks around
// the camera (within 2 m), as fusion would.
struct Walk {
  PointMap map{0.5};
  std::map<ChunkKey, PointArrays, KeyLess> reference;  // what every chunk should hold
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
        ch.points.append(add);
        ch.last_touched_frame = frame;
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
  config.memory_budget_mib = 1.0;
  config.evict_distance_m = 3.0;
  config.load_radius_m = 2.5;
  ASSERT_TRUE(MapPager::validate(config));
  MapPager pager(config, store->get());
  Walk walk;
  const size_t budget = static_cast<size_t>(config.memory_budget_mib * 1024 * 1024);
  size_t max_resident = 0;
  const int steps = 400;  // 100 m out, then back
  for (int i = 0; i <= 2 * steps; ++i) {
    const Eigen::Vector3f cam = walk.camera(i <= steps ? i : 2 * steps - i);
    ASSERT_TRUE(pager.update(&walk.map, cam)) << pager.stats().last_error;  // loads what is near
    walk.fuse_at(cam);
    ASSERT_TRUE(pager.update(&walk.map, cam)) << pager.stats().last_error;
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
      EXPECT_TRUE(bit_equal(c->points, points)) << to_string(k);
    }
  }
  // And every evicted chunk in the store is exactly the reference.
  for (const ChunkKey& k : pager.evicted()) {
    auto c = (*store)->read_chunk(k, /*include_staged=*/true);
    ASSERT_TRUE(c) << c.status().to_string();
    EXPECT_TRUE(bit_equal(c->chunk.points, walk.reference.at(k))) << to_string(k);
  }
}

TEST(MapPager, LoadsOnlyWithinTheRadiusAndNeverEvictsNearChunks) {
  TempDir dir;
  auto store = ScanStore::open(dir.file("scan.db"), OpenMode::kCreate);
  ASSERT_TRUE(store);
  MapPagerConfig config;
  config.memory_budget_mib = 0.01;  // far below what the near chunks need
  config.evict_distance_m = 2.0;
  config.load_radius_m = 1.5;
  MapPager pager(config, store->get());
  PointMap map(0.5);
  for (int x = -20; x <= 20; ++x) {
    Chunk& c = map.get_or_create({x, 0, 0});
    c.points = make_points({x, 0, 0}, 1, 50);
  }
  const Eigen::Vector3f cam(0.25f, 0.25f, 0.25f);
  ASSERT_TRUE(pager.update(&map, cam));
  // Everything farther than 2 m went; what is nearer stayed although the budget is exceeded.
  map.for_each_chunk([&](const ChunkKey& k, const Chunk&) {
    EXPECT_LE(distance_to_chunk_m(map, k, cam), 2.0f) << to_string(k);
  });
  EXPECT_EQ(map.chunk_count(), 9u);  // keys -4..4: the chunk at 2 m exactly stays
  EXPECT_GT(pager.stats().unevictable_bytes, 0u);
  // Moving 3 m along x loads exactly the evicted chunks within 1.5 m: x in [1.75, 4.75] m, keys
  // 3 .. 9, of which 5 .. 9 were evicted.
  const Eigen::Vector3f cam2(3.25f, 0.25f, 0.25f);
  const uint64_t loaded_before = pager.stats().total_loaded;
  ASSERT_TRUE(pager.update(&map, cam2));
  EXPECT_EQ(pager.stats().total_loaded - loaded_before, 5u);
  for (int x = 3; x <= 9; ++x) EXPECT_NE(map.find({x, 0, 0}), nullptr) << x;
  EXPECT_EQ(map.find({10, 0, 0}), nullptr);
}

TEST(MapPager, RejectsAConfigThatWouldThrash) {
  MapPagerConfig c;
  c.load_radius_m = 7.0;
  c.evict_distance_m = 6.0;
  EXPECT_FALSE(MapPager::validate(c));
  c.memory_budget_mib = 0;
  c.load_radius_m = 5.0;
  EXPECT_FALSE(MapPager::validate(c));
}
