// Scene geometry: exact distances and raycasts on known configurations, the acceleration grid
// against brute force, multipath edge distances, and the TOML round trip.
#include <gtest/gtest.h>

#include <cmath>
#include <limits>
#include <string>
#include <vector>

#include "depthfuse/synthetic/scene.hpp"

namespace depthfuse::synthetic {
namespace {

using Eigen::Vector3d;
constexpr double kInf = std::numeric_limits<double>::infinity();

Scene single_box(PrimitiveKind kind) {
  Primitive p = kind == PrimitiveKind::kBox ? Primitive::box(Vector3d(0, 0, 0), Vector3d(1, 1, 1))
                                            : Primitive::room(Vector3d(0, 0, 0), Vector3d(1, 1, 1));
  auto scene = Scene::create({p});
  EXPECT_TRUE(scene.is_ok()) << scene.status().to_string();
  return std::move(scene).value();
}

TEST(SceneKind, ParseAndPrint) {
  for (SceneKind k : {SceneKind::kCorner, SceneKind::kRoom, SceneKind::kRooms}) {
    auto parsed = parse_scene_kind(to_string(k));
    ASSERT_TRUE(parsed.is_ok());
    EXPECT_EQ(parsed.value(), k);
  }
  EXPECT_STREQ(to_string(SceneKind::kCorner), "corner");
  EXPECT_STREQ(to_string(SceneKind::kRooms), "rooms");
  auto bad = parse_scene_kind("kitchen");
  ASSERT_FALSE(bad.is_ok());
  EXPECT_EQ(bad.status().code(), StatusCode::kInvalidArgument);
  EXPECT_NE(bad.status().message().find("kitchen"), std::string::npos);
}

TEST(Scene, CornerDistanceAtKnownPoints) {
  const Scene s = Scene::make(SceneKind::kCorner, 1);
  ASSERT_EQ(s.primitives().size(), 3u);
  EXPECT_NEAR(s.distance_m(Vector3d(1, 1, 1)), 1.0, 1e-12);
  EXPECT_NEAR(s.distance_m(Vector3d(0.5, 2, 0.2)), 0.2, 1e-12);         // above the floor
  EXPECT_NEAR(s.distance_m(Vector3d(-1, 1, 1)), 1.0, 1e-12);            // behind the x = 0 wall
  EXPECT_NEAR(s.distance_m(Vector3d(4, 1, 1)), std::sqrt(2.0), 1e-12);  // past the planes' ends
  EXPECT_NEAR(s.distance_m(Vector3d(1, 1, 5)), std::sqrt(5.0), 1e-12);  // above the walls' tops
  EXPECT_NEAR(s.distance_m(Vector3d(0.3, 0.0, 0.7)), 0.0, 1e-12);       // on a wall
}

TEST(Scene, BoxAndRoomDistance) {
  for (PrimitiveKind kind : {PrimitiveKind::kBox, PrimitiveKind::kRoom}) {
    const Scene s = single_box(kind);
    EXPECT_NEAR(s.distance_m(Vector3d(0.5, 0.5, 2.0)), 1.0, 1e-12);
    EXPECT_NEAR(s.distance_m(Vector3d(0.5, 0.6, 0.4)), 0.4, 1e-12);  // inside: nearest face
    EXPECT_NEAR(s.distance_m(Vector3d(2, 2, 2)), std::sqrt(3.0), 1e-12);
    EXPECT_NEAR(s.distance_m(Vector3d(1.0, 0.5, 0.5)), 0.0, 1e-12);
  }
  EXPECT_EQ(Scene().distance_m(Vector3d::Zero()), kInf);
}

TEST(Scene, RaycastHitsAndNormalsFaceTheOrigin) {
  const Scene corner = Scene::make(SceneKind::kCorner, 1);
  double t = 0;
  Vector3d n;
  ASSERT_TRUE(corner.raycast(Vector3d(1, 1, 1), Vector3d(-1, 0, 0), &t, &n));
  EXPECT_NEAR(t, 1.0, 1e-12);
  EXPECT_TRUE(n.isApprox(Vector3d(1, 0, 0)));
  ASSERT_TRUE(corner.raycast(Vector3d(1, 1, 1), Vector3d(0, 0, -2), &t, &n));
  EXPECT_NEAR(t, 0.5, 1e-12);  // t counts in multiples of a non-unit direction
  EXPECT_TRUE(n.isApprox(Vector3d(0, 0, 1)));
  // From behind the wall the normal faces the other way.
  ASSERT_TRUE(corner.raycast(Vector3d(-1, 1, 1), Vector3d(1, 0, 0), &t, &n));
  EXPECT_NEAR(t, 1.0, 1e-12);
  EXPECT_TRUE(n.isApprox(Vector3d(-1, 0, 0)));
  // Oblique: down and towards the x = 0 wall, the floor comes first, at (1, 2, 0).
  ASSERT_TRUE(corner.raycast(Vector3d(2, 2, 1), Vector3d(-1, 0, -1).normalized(), &t, &n));
  EXPECT_NEAR(t, std::sqrt(2.0), 1e-12);
  EXPECT_FALSE(corner.raycast(Vector3d(1, 1, 1), Vector3d(1, 1, 1), &t, &n));  // out of the corner
  EXPECT_FALSE(
      corner.raycast(Vector3d(1, 1, 1), Vector3d(-1, 0, 0), 0.5, nullptr));  // beyond t_max

  const Scene box = single_box(PrimitiveKind::kBox);
  RayHit hit;
  ASSERT_TRUE(box.raycast(Vector3d(-1, 0.5, 0.25), Vector3d(1, 0, 0), kInf, &hit));
  EXPECT_NEAR(hit.t, 1.0, 1e-12);
  EXPECT_TRUE(hit.normal_w.isApprox(Vector3d(-1, 0, 0)));
  EXPECT_EQ(hit.face, 0);  // min side of x
  EXPECT_NEAR(hit.uv_m.x(), 0.5, 1e-12);
  EXPECT_NEAR(hit.uv_m.y(), 0.25, 1e-12);
  ASSERT_TRUE(box.raycast(Vector3d(0.5, 0.5, 3), Vector3d(0, 0, -1), kInf, &hit));
  EXPECT_NEAR(hit.t, 2.0, 1e-12);
  EXPECT_TRUE(hit.normal_w.isApprox(Vector3d(0, 0, 1)));

  const Scene room = single_box(PrimitiveKind::kRoom);
  ASSERT_TRUE(room.raycast(Vector3d(0.25, 0.5, 0.5), Vector3d(1, 0, 0), kInf, &hit));
  EXPECT_NEAR(hit.t, 0.75, 1e-12);
  EXPECT_TRUE(hit.normal_w.isApprox(Vector3d(-1, 0, 0)));  // the wall's inside faces the camera
  EXPECT_EQ(hit.face, 1);
}

// The grid is an acceleration only: it must give exactly what testing every primitive gives.
TEST(Scene, GridMatchesBruteForceOnManyRooms) {
  const Scene s = Scene::make(SceneKind::kRooms, 3);
  ASSERT_GT(s.primitives().size(), 60u);
  std::vector<Scene> singles;
  for (const Primitive& p : s.primitives()) {
    auto one = Scene::create({p});
    ASSERT_TRUE(one.is_ok());
    singles.push_back(std::move(one).value());
  }
  uint64_t state = 12345;
  auto rnd = [&state]() {
    state = state * 6364136223846793005ull + 1442695040888963407ull;
    return static_cast<double>(state >> 11) * 0x1.0p-53;
  };
  int hits = 0;
  for (int k = 0; k < 1500; ++k) {
    const Vector3d o(-1 + 22 * rnd(), -1 + 22 * rnd(), 0.1 + 2.4 * rnd());
    Vector3d d(rnd() - 0.5, rnd() - 0.5, 0.6 * (rnd() - 0.5));
    if (k % 50 == 0) d = Vector3d(0, 0, 1);    // straight up: a single grid cell
    if (k % 50 == 1) d = Vector3d(1, 0, 0.1);  // along a grid axis
    RayHit grid_hit;
    const bool grid = s.raycast(o, d, kInf, &grid_hit);
    double best = kInf;
    for (const Scene& one : singles) {
      RayHit h;
      if (one.raycast(o, d, kInf, &h)) best = std::min(best, h.t);
    }
    ASSERT_EQ(grid, best < kInf) << "ray " << k;
    if (grid) {
      ++hits;
      EXPECT_NEAR(grid_hit.t, best, 1e-9) << "ray " << k;
    }
    // distance_m at the same random point.
    double dist = kInf;
    for (const Scene& one : singles) dist = std::min(dist, one.distance_m(o));
    EXPECT_NEAR(s.distance_m(o), dist, 1e-12) << "point " << k;
  }
  EXPECT_GT(hits, 1000);
}

TEST(Scene, ConcaveEdgeDistance) {
  const Scene corner = Scene::make(SceneKind::kCorner, 1);
  // On the floor (primitive 0), 5 cm from the x = 0 wall, far from the other one.
  EXPECT_NEAR(corner.concave_edge_distance_m(Vector3d(0.05, 1.0, 0), Vector3d::UnitZ(), 0, 0, 1.0),
              0.05, 1e-12);
  EXPECT_NEAR(corner.concave_edge_distance_m(Vector3d(0.3, 0.1, 0), Vector3d::UnitZ(), 0, 0, 1.0),
              0.1, 1e-12);
  EXPECT_EQ(corner.concave_edge_distance_m(Vector3d(1.5, 1.5, 0), Vector3d::UnitZ(), 0, 0, 0.15),
            0.15);

  // A box on a floor: concave where it meets the floor, convex along its top edges.
  auto s = Scene::create({Primitive::plane(Vector3d::Zero(), Vector3d::UnitZ(), Vector3d::UnitX(),
                                           -5, 5, -5, 5, "floor"),
                          Primitive::box(Vector3d(0, 0, 0), Vector3d(1, 1, 0.5), "box")});
  ASSERT_TRUE(s.is_ok());
  EXPECT_NEAR(s->concave_edge_distance_m(Vector3d(1.04, 0.5, 0), Vector3d::UnitZ(), 0, 0, 1.0),
              0.04,
              1e-12);  // floor beside the box
  EXPECT_NEAR(s->concave_edge_distance_m(Vector3d(1.0, 0.5, 0.07), Vector3d::UnitX(), 1, 1, 1.0),
              0.07,
              1e-12);  // box side just above the floor
  EXPECT_EQ(s->concave_edge_distance_m(Vector3d(0.98, 0.5, 0.5), Vector3d::UnitZ(), 1, 5, 0.15),
            0.15);  // box top next to its edge: convex, no multipath
  // Inside a room every edge is concave.
  const Scene room = single_box(PrimitiveKind::kRoom);
  EXPECT_NEAR(room.concave_edge_distance_m(Vector3d(0.5, 0.03, 0.0), Vector3d::UnitZ(), 0, 4, 1.0),
              0.03, 1e-12);
}

TEST(Scene, BuiltInScenesHaveTheDescribedLayout) {
  const Scene room = Scene::make(SceneKind::kRoom, 7);
  ASSERT_EQ(room.primitives().size(), 6u);
  EXPECT_EQ(room.primitives()[0].kind, PrimitiveKind::kRoom);
  // One box stands on another.
  const Primitive& base = room.primitives()[1];
  const Primitive& top = room.primitives()[2];
  EXPECT_DOUBLE_EQ(top.min_m.z(), base.max_m.z());
  EXPECT_TRUE((top.min_m.head<2>().array() > base.min_m.head<2>().array()).all());
  EXPECT_TRUE((top.max_m.head<2>().array() < base.max_m.head<2>().array()).all());
  for (size_t i = 1; i < room.primitives().size(); ++i) {
    const Primitive& b = room.primitives()[i];
    EXPECT_EQ(b.kind, PrimitiveKind::kBox);
    EXPECT_GE(b.min_m.x(), 0.1);
    EXPECT_GE(b.min_m.y(), 0.1);
    EXPECT_LE(b.max_m.x(), 4.9);
    EXPECT_LE(b.max_m.y(), 3.9);
  }
  // The seed changes the layout, and only the seed.
  EXPECT_EQ(Scene::make(SceneKind::kRoom, 7).to_toml(), room.to_toml());
  EXPECT_NE(Scene::make(SceneKind::kRoom, 8).to_toml(), room.to_toml());

  const Scene rooms = Scene::make(SceneKind::kRooms, 1);
  EXPECT_NEAR(rooms.bounds().max().x() - rooms.bounds().min().x(), 20.1, 1e-9);
  EXPECT_NEAR(rooms.bounds().max().z(), 2.6, 1e-9);
  int boxes = 0;
  for (const Primitive& p : rooms.primitives()) boxes += p.name.rfind("box_", 0) == 0 ? 1 : 0;
  EXPECT_GE(boxes, 32);  // two or three per room, some stacked
}

TEST(SceneToml, RoundTripIsExact) {
  for (SceneKind kind : {SceneKind::kCorner, SceneKind::kRoom, SceneKind::kRooms}) {
    const Scene s = Scene::make(kind, 42);
    const std::string text = s.to_toml();
    auto back = Scene::parse_toml(text);
    ASSERT_TRUE(back.is_ok()) << back.status().to_string();
    EXPECT_EQ(back->name(), s.name());
    ASSERT_EQ(back->primitives().size(), s.primitives().size());
    for (size_t i = 0; i < s.primitives().size(); ++i) {
      const Primitive& a = s.primitives()[i];
      const Primitive& b = back->primitives()[i];
      EXPECT_EQ(a.kind, b.kind);
      EXPECT_EQ(a.name, b.name);
      EXPECT_EQ(a.color_rgb, b.color_rgb);
      EXPECT_EQ(a.min_m, b.min_m);  // bit-exact doubles
      EXPECT_EQ(a.max_m, b.max_m);
      if (a.kind == PrimitiveKind::kPlane) {
        EXPECT_EQ(a.origin_m, b.origin_m);
        EXPECT_EQ(a.normal, b.normal);
        EXPECT_EQ(a.u_axis, b.u_axis);
        EXPECT_EQ(a.u_min_m, b.u_min_m);
        EXPECT_EQ(a.v_max_m, b.v_max_m);
      }
    }
    EXPECT_EQ(back->to_toml(), text);
  }
}

TEST(SceneToml, UnboundedPlanesAndGeneratorTablesAreAccepted) {
  const std::string text = R"(
[scene]
name = "wall"

[[primitive]]
kind = "plane"
origin_m = [0, 0, 2]
normal = [0, 0, -1]
u_axis = [1, 0, 0]
u_range_m = [-inf, inf]
v_range_m = [0, inf]

[generator]
scene = "corner"
)";
  auto s = Scene::parse_toml(text, "wall.toml");
  ASSERT_TRUE(s.is_ok()) << s.status().to_string();
  double t = 0;
  // v_axis = normal x u_axis = -y, so v >= 0 is the half-plane y <= 0.
  EXPECT_TRUE(s->raycast(Vector3d(100, -1, 0), Vector3d(0, 0, 1), &t, nullptr));
  EXPECT_NEAR(t, 2.0, 1e-12);
  EXPECT_FALSE(s->raycast(Vector3d(100, 1, 0), Vector3d(0, 0, 1), &t, nullptr));
  auto again = Scene::parse_toml(s->to_toml());
  ASSERT_TRUE(again.is_ok()) << again.status().to_string();
  EXPECT_EQ(again->primitives()[0].u_min_m, -kInf);
}

TEST(SceneToml, ErrorsNameTheProblem) {
  auto expect_error = [](const std::string& text, const std::string& needle) {
    auto s = Scene::parse_toml(text, "bad.toml");
    ASSERT_FALSE(s.is_ok()) << "accepted: " << text;
    EXPECT_EQ(s.status().code(), StatusCode::kInvalidArgument);
    EXPECT_NE(s.status().message().find(needle), std::string::npos)
        << "'" << s.status().message() << "' lacks '" << needle << "'";
  };
  expect_error("[[primitive]]\nkind = \"box\"\nmin_m = [0,0,0]\nmax_m = [1,1,1]\nsize = 3\n",
               "bad.toml:5: primitive[0].size: unknown key");
  expect_error("[[primitive]]\nkind = \"sphere\"\n", "sphere");
  expect_error("[[primitive]]\nkind = \"box\"\nmin_m = [0,0,0]\n",
               "primitive[0].max_m: missing");
  expect_error("[[primitive]]\nkind = \"box\"\nmin_m = [0,0,0]\nmax_m = [1,-1,1]\n",
               "primitive 0 (box)");
  expect_error("[[primitive]]\nkind = \"box\"\nmin_m = [0,0]\nmax_m = [1,1,1]\n",
               "array of 3 numbers");
  expect_error(
      "[[primitive]]\nkind = \"plane\"\norigin_m = [0,0,0]\nnormal = [0,0,1]\nu_axis = [0,0,1]\n"
      "u_range_m = [0,1]\nv_range_m = [0,1]\n",
      "perpendicular");
  expect_error("[scene]\nname = \"x\"\nformat_version = 9\n", "format_version 9");
  expect_error("[scene\n", "bad.toml:1");
  expect_error("stray = 1\n", "bad.toml:1: stray: unknown key");
  expect_error("[[primitive]]\nkind = \"box\"\nmin_m = [0,0,0]\nmax_m = [1,1,1]\nchecker_m = -1\n",
               "bad.toml:5: primitive[0].checker_m: must be >= 0, got -1");
  // Every problem of the file at once, in the order of the file.
  expect_error("[[primitive]]\nkind = \"box\"\nmin_m = [0,0,\"x\"]\nmax_m = [1,1,1]\n"
               "[[primitive]]\nkind = \"room\"\nmin_m = [0,0,0]\nmax_m = [1,1,1]\ncolor_rgb = [0, 0, 300]\n",
               "bad.toml:3: primitive[0].min_m[2]: expected a number, got a string\n"
               "bad.toml:9: primitive[1].color_rgb[2]: must be in [0, 255], got 300");
  auto missing = Scene::load_toml("/nonexistent/scene.toml");
  ASSERT_FALSE(missing.is_ok());
  EXPECT_EQ(missing.status().code(), StatusCode::kNotFound);
  EXPECT_NE(missing.status().message().find("/nonexistent/scene.toml"), std::string::npos);
}

}  // namespace
}  // namespace depthfuse::synthetic
