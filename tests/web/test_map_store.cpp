// The monitor's copy of the map for its pages (apps/monitor/map_store.hpp): how a loop closure's
// correction (graph_correction_t) moves the camera's path the pages draw, and what it refuses.
#include <gtest/gtest.h>

#include <cmath>
#include <cstdlib>
#include <memory>
#include <string>
#include <vector>

#include "keyframe_motions.hpp"
#include "map_store.hpp"

namespace depthfuse::monitor {
namespace {

constexpr double kPi = 3.14159265358979323846;

// A delta without chunks: the camera at x = 0.1 m * frame_sequence on the x axis.
depthfuse::map_delta_t delta(int64_t sequence, int64_t frame_sequence,
                             const std::string& scan_id = "scan-a") {
  depthfuse::map_delta_t m{};
  m.protocol_version = depthfuse::map_delta_t::PROTOCOL_VERSION;
  m.sender = "fusion";
  m.scan_id = scan_id;
  m.sequence = sequence;
  m.has_pose = true;
  m.frame_sequence = frame_sequence;
  m.position_m[0] = 0.1 * static_cast<double>(frame_sequence);
  m.orientation_wxyz[0] = 1;
  m.chunk_size_m = 0.5f;
  m.position_unit_m = 1e-5f;
  m.uncertainty_unit_m = 1e-5f;
  return m;
}

struct Motion {
  int64_t first_sequence;
  double t[3];
  double yaw_deg;  // about z
};

depthfuse::graph_correction_t correction(const std::vector<Motion>& motions,
                                         const std::string& scan_id = "scan-a") {
  depthfuse::graph_correction_t c{};
  c.protocol_version = depthfuse::graph_correction_t::PROTOCOL_VERSION;
  c.sender = "fusion";
  c.scan_id = scan_id;
  c.version = 1;
  c.loops = 2;
  c.max_translation_m = 0.5;
  c.num_keyframes = static_cast<int32_t>(motions.size());
  c.num_translations = 3 * c.num_keyframes;
  c.num_rotations = 4 * c.num_keyframes;
  for (const Motion& m : motions) {
    c.first_sequence.push_back(m.first_sequence);
    for (double v : m.t) c.motion_translation_m.push_back(v);
    const double half = m.yaw_deg * kPi / 360;
    for (double v : {std::cos(half), 0.0, 0.0, std::sin(half)}) c.motion_orientation_wxyz.push_back(v);
  }
  return c;
}

struct Page {
  MapStore::Cursor cursor;
  std::vector<std::string> text;
  // Takes what the page lacks.
  void poll(const MapStore& store) {
    text.clear();
    std::vector<std::shared_ptr<const std::vector<uint8_t>>> chunks;
    store.changes(&cursor, 1 << 20, &text, &chunks);
  }
  const std::string* find(const std::string& type) const {
    for (const auto& t : text)
      if (t.find("\"type\": \"" + type + "\"") != std::string::npos) return &t;
    return nullptr;
  }
};

// The numbers of a JSON array field, e.g. "xyz": [1, 2].
std::vector<double> numbers(const std::string& json, const std::string& field) {
  std::vector<double> out;
  size_t at = json.find("\"" + field + "\": [");
  if (at == std::string::npos) return out;
  const char* p = json.c_str() + json.find('[', at) + 1;
  while (*p && *p != ']') {
    char* end = nullptr;
    out.push_back(std::strtod(p, &end));
    p = end;
    while (*p == ',' || *p == ' ') ++p;
  }
  return out;
}

class MapStoreCorrection : public ::testing::Test {
 protected:
  void SetUp() override {
    for (int64_t i = 1; i <= 10; ++i) feed(i, i);  // frames 1..10, x = 0.1 .. 1.0 m
    page.poll(store);
    ASSERT_NE(page.find("trajectory"), nullptr);
    ASSERT_EQ(numbers(*page.find("trajectory"), "xyz").size(), 30u);
  }
  void feed(int64_t sequence, int64_t frame_sequence) {
    bool want = false;
    ASSERT_EQ(store.apply(delta(sequence, frame_sequence), &want), MapStore::Accepted::kOk);
  }
  MapStore store;
  Page page;
};

TEST_F(MapStoreCorrection, MovesEachPositionWithItsKeyframeAndSendsThePathAgain) {
  // Keyframes at frames 4 and 8: frames 1-3 stay, 4-7 move by +1 m in y, 8-10 turn 90 degrees
  // about z and then move by +2 m in z.
  Status problem;
  ASSERT_EQ(store.apply(correction({{4, {0, 1, 0}, 0}, {8, {0, 0, 2}, 90}}), &problem),
            MapStore::Accepted::kOk)
      << problem.to_string();
  page.poll(store);
  const std::string* path = page.find("trajectory");
  ASSERT_NE(path, nullptr) << "no path after the correction";
  EXPECT_NE(path->find("\"from\": 0"), std::string::npos) << *path;
  const std::vector<double> xyz = numbers(*path, "xyz");
  ASSERT_EQ(xyz.size(), 30u);
  for (int i = 0; i < 10; ++i) {
    const double x = 0.1 * (i + 1);
    double expect[3] = {x, 0, 0};
    if (i + 1 >= 8) expect[0] = 0, expect[1] = x, expect[2] = 2;
    else if (i + 1 >= 4) expect[1] = 1;
    for (int k = 0; k < 3; ++k)
      EXPECT_NEAR(xyz[3 * i + k], expect[k], 1e-5) << "frame " << i + 1 << " axis " << k;
  }
  // The camera, at frame 10, moved with its keyframe too; and the page is told once.
  const std::string* pose = page.find("pose");
  ASSERT_NE(pose, nullptr);
  const std::vector<double> p = numbers(*pose, "position_m");
  ASSERT_EQ(p.size(), 3u);
  EXPECT_NEAR(p[0], 0, 1e-9);
  EXPECT_NEAR(p[1], 1.0, 1e-9);
  EXPECT_NEAR(p[2], 2.0, 1e-9);
  const std::string* note = page.find("correction");
  ASSERT_NE(note, nullptr);
  EXPECT_NE(note->find("\"poses_moved\": 7"), std::string::npos) << *note;
  page.poll(store);
  EXPECT_TRUE(page.text.empty()) << page.text.front();

  // A page that joins now gets the corrected path, without a note of a correction before it.
  Page late;
  late.poll(store);
  ASSERT_NE(late.find("trajectory"), nullptr);
  EXPECT_EQ(numbers(*late.find("trajectory"), "xyz"), xyz);
  EXPECT_EQ(late.find("correction"), nullptr);

  // Poses after the correction come corrected already: they are appended, and a second correction
  // moves them with the rest.
  feed(11, 11);
  ASSERT_EQ(store.apply(correction({{1, {0, 0, -2}, 0}}), &problem), MapStore::Accepted::kOk);
  page.poll(store);
  const std::vector<double> again = numbers(*page.find("trajectory"), "xyz");
  ASSERT_EQ(again.size(), 33u);
  EXPECT_NEAR(again[2], -2, 1e-5);
  EXPECT_NEAR(again[29], 0, 1e-5);
  EXPECT_NEAR(again[30], 1.1, 1e-5);
  EXPECT_NEAR(again[32], -2, 1e-5);
}

TEST_F(MapStoreCorrection, TheLastKeyframeInTheMessagesOrderTakesAFrame) {
  // Sequences out of order (a capture that restarted): frame 6 belongs to the keyframe listed
  // last among those starting at or before it, the one at 2.
  Status problem;
  ASSERT_EQ(store.apply(correction({{5, {0, 1, 0}, 0}, {2, {0, 2, 0}, 0}, {9, {0, 3, 0}, 0}}), &problem),
            MapStore::Accepted::kOk);
  page.poll(store);
  const std::vector<double> xyz = numbers(*page.find("trajectory"), "xyz");
  ASSERT_EQ(xyz.size(), 30u);
  const double expect_y[10] = {0, 2, 2, 2, 2, 2, 2, 2, 3, 3};
  for (int i = 0; i < 10; ++i) EXPECT_NEAR(xyz[3 * i + 1], expect_y[i], 1e-6) << "frame " << i + 1;
}

TEST_F(MapStoreCorrection, OneOfAnotherScanOrSenderChangesNothing) {
  Status problem;
  EXPECT_EQ(store.apply(correction({{1, {0, 1, 0}, 0}}, "scan-b"), &problem), MapStore::Accepted::kOtherScan);
  EXPECT_NE(problem.message().find("scan-b"), std::string::npos) << problem.to_string();
  auto other = correction({{1, {0, 1, 0}, 0}});
  other.sender = "fusion-2";
  EXPECT_EQ(store.apply(other, &problem), MapStore::Accepted::kOtherScan);
  page.poll(store);
  EXPECT_TRUE(page.text.empty()) << page.text.front();
}

TEST_F(MapStoreCorrection, BrokenOrOversizedCorrectionsAreRefusedWithTheReason) {
  struct Case {
    const char* what;
    void (*spoil)(depthfuse::graph_correction_t*);
    const char* says;
  };
  const Case cases[] = {
      {"num_translations", [](depthfuse::graph_correction_t* c) { c->num_translations = 4; }, "arrays"},
      {"short array", [](depthfuse::graph_correction_t* c) { c->motion_orientation_wxyz.pop_back(); }, "arrays"},
      {"first_sequence", [](depthfuse::graph_correction_t* c) { c->first_sequence.push_back(3); }, "arrays"},
      {"negative count", [](depthfuse::graph_correction_t* c) { c->num_keyframes = -1; }, "-1 keyframes"},
      {"not finite", [](depthfuse::graph_correction_t* c) { c->motion_translation_m[1] = NAN; }, "finite"},
      {"zero rotation",
       [](depthfuse::graph_correction_t* c) { for (auto& q : c->motion_orientation_wxyz) q = 0; }, "rotation"},
      {"far", [](depthfuse::graph_correction_t* c) { c->motion_translation_m[0] = 1e6; }, "more than"},
      {"max_translation_m", [](depthfuse::graph_correction_t* c) { c->max_translation_m = INFINITY; }, "finite"},
  };
  for (const Case& k : cases) {
    auto c = correction({{1, {0, 1, 0}, 0}});
    k.spoil(&c);
    Status problem;
    EXPECT_EQ(store.apply(c, &problem), MapStore::Accepted::kMalformed) << k.what;
    EXPECT_NE(problem.message().find(k.says), std::string::npos) << k.what << ": " << problem.to_string();
  }
  // One keyframe beyond the bound, every array consistent.
  std::vector<Motion> many(static_cast<size_t>(KeyframeMotions::kMaxKeyframes) + 1, Motion{1, {0, 1, 0}, 0});
  Status problem;
  EXPECT_EQ(store.apply(correction(many), &problem), MapStore::Accepted::kMalformed);
  EXPECT_NE(problem.message().find("at most"), std::string::npos) << problem.to_string();
  page.poll(store);
  EXPECT_TRUE(page.text.empty()) << page.text.front();
}

}  // namespace
}  // namespace depthfuse::monitor
