// The built-in scenes. Their layouts leave the free space that trajectory.cpp moves the camera
// through: if you move a box here, check the clearances noted next to it.
#include <cmath>
#include <string>
#include <utility>
#include <vector>

#include "depthfuse/synthetic/scene.hpp"
#include "lap_rooms.hpp"
#include "random.hpp"
#include "rooms_layout.hpp"
#include "scene_parts.hpp"

namespace depthfuse::synthetic {

namespace {

using Eigen::Vector3d;
using scene_parts::colored;
using scene_parts::jittered_box;
using scene_parts::random_colored;

// Floor and two walls of 3 x 3 m meeting at the origin (the paper's CCorner); the free space is
// x, y, z > 0.
std::vector<Primitive> make_corner() {
  std::vector<Primitive> p;
  p.push_back(colored(Primitive::plane(Vector3d::Zero(), Vector3d::UnitZ(), Vector3d::UnitX(), 0.0,
                                       3.0, 0.0, 3.0, "floor"),
                      170, 160, 150));
  // Wall in the plane x = 0: u = +y, v = n x u = +z.
  p.push_back(colored(Primitive::plane(Vector3d::Zero(), Vector3d::UnitX(), Vector3d::UnitY(), 0.0,
                                       3.0, 0.0, 3.0, "wall_x0"),
                      200, 190, 140));
  // Wall in the plane y = 0: u = +z, v = n x u = +x.
  p.push_back(colored(Primitive::plane(Vector3d::Zero(), Vector3d::UnitY(), Vector3d::UnitZ(), 0.0,
                                       3.0, 0.0, 3.0, "wall_y0"),
                      140, 180, 200));
  return p;
}

// A 5 x 4 x 2.6 m room with five boxes near the walls, one stacked on another. The camera loop of
// trajectory.cpp stays within x in [1.8, 3.2], y in [1.55, 2.45]; every box keeps >= 0.1 m from the
// walls and ends at least 0.75 m from that loop.
std::vector<Primitive> make_room(uint64_t seed) {
  detail::HashRng rng(detail::stream_key(seed, detail::kStreamSceneLayout, 1));
  std::vector<Primitive> p;
  p.push_back(
      colored(Primitive::room(Vector3d(0, 0, 0), Vector3d(5.0, 4.0, 2.6), "room"), 190, 185, 175));
  // Each box: nominal footprint, height, and the region its jittered footprint must stay in.
  const Primitive base = jittered_box(
      &rng, 0.2, 0.8, 0.8, 1.6, 0.0, 0.5, 0.08,
      Eigen::AlignedBox2d(Eigen::Vector2d(0.1, 0.3), Eigen::Vector2d(1.0, 2.4)), "box_stack_base");
  p.push_back(base);
  // On top of it: smaller, set back from its edges.
  {
    const double w = (base.max_m.x() - base.min_m.x()) * rng.uniform(0.45, 0.65);
    const double d = (base.max_m.y() - base.min_m.y()) * rng.uniform(0.45, 0.65);
    const double cx = 0.5 * (base.min_m.x() + base.max_m.x()) + rng.uniform(-0.04, 0.04);
    const double cy = 0.5 * (base.min_m.y() + base.max_m.y()) + rng.uniform(-0.06, 0.06);
    const double h = rng.uniform(0.25, 0.35);
    p.push_back(random_colored(
        Primitive::box(Vector3d(cx - 0.5 * w, cy - 0.5 * d, base.max_m.z()),
                       Vector3d(cx + 0.5 * w, cy + 0.5 * d, base.max_m.z() + h), "box_stack_top"),
        &rng));
  }
  p.push_back(jittered_box(
      &rng, 4.1, 4.8, 2.9, 3.8, 0.0, 0.9, 0.08,
      Eigen::AlignedBox2d(Eigen::Vector2d(3.9, 2.6), Eigen::Vector2d(4.9, 3.9)), "box_tall"));
  p.push_back(jittered_box(
      &rng, 2.6, 3.6, 0.2, 0.7, 0.0, 0.4, 0.1,
      Eigen::AlignedBox2d(Eigen::Vector2d(1.8, 0.1), Eigen::Vector2d(4.4, 0.8)), "box_long"));
  p.push_back(jittered_box(
      &rng, 1.3, 1.8, 3.3, 3.8, 0.0, 0.7, 0.08,
      Eigen::AlignedBox2d(Eigen::Vector2d(0.8, 3.2), Eigen::Vector2d(2.4, 3.9)), "box_cube"));
  return p;
}

}  // namespace

namespace {

// Floor and ceiling over the whole grid, out to the outer walls' outer faces.
void add_rooms_floor_and_ceiling(std::vector<Primitive>* p) {
  using namespace rooms_layout;
  const double extent = kRoomsN * kCellM;
  const double hw = 0.5 * kWallM;
  p->push_back(colored(Primitive::plane(Vector3d::Zero(), Vector3d::UnitZ(), Vector3d::UnitX(), -hw,
                                        extent + hw, -hw, extent + hw, "floor"),
                       165, 155, 145));
  // Ceiling facing down: u = +y, v = n x u = +x.
  p->push_back(
      colored(Primitive::plane(Vector3d(0, 0, kHeightM), -Vector3d::UnitZ(), Vector3d::UnitY(), -hw,
                               extent + hw, -hw, extent + hw, "ceiling"),
              230, 230, 225));
}

// Walls: along each grid line, pieces between doorways; a lintel (slightly thinner, so that its
// faces are not coplanar with the wall's) above each doorway.
void add_rooms_walls(std::vector<Primitive>* p) {
  using namespace rooms_layout;
  const double extent = kRoomsN * kCellM;
  const double hw = 0.5 * kWallM;
  for (int axis = 0; axis < 2; ++axis) {  // 0: walls along x (at y = j * cell), 1: along y
    for (int j = 0; j <= kRoomsN; ++j) {
      const double c = j * kCellM;
      const bool inner = j > 0 && j < kRoomsN;
      std::vector<std::pair<double, double>> pieces;
      double start = -hw;
      if (inner) {
        for (int i = 0; i < kRoomsN; ++i) {
          const double door_mid = (i + 0.5) * kCellM;
          pieces.emplace_back(start, door_mid - 0.5 * kDoorM);
          start = door_mid + 0.5 * kDoorM;
        }
      }
      pieces.emplace_back(start, extent + hw);
      auto make = [&](double a0, double a1, double t, double z0, double z1,
                      const std::string& name) {
        Vector3d lo, hi;
        if (axis == 0) {
          lo = Vector3d(a0, c - t, z0);
          hi = Vector3d(a1, c + t, z1);
        } else {
          lo = Vector3d(c - t, a0, z0);
          hi = Vector3d(c + t, a1, z1);
        }
        return colored(Primitive::box(lo, hi, name), 200, 195, 185);
      };
      const std::string line = std::string(axis == 0 ? "wall_y" : "wall_x") + std::to_string(j);
      for (size_t k = 0; k < pieces.size(); ++k)
        p->push_back(make(pieces[k].first, pieces[k].second, hw, 0.0, kHeightM,
                          line + "_" + std::to_string(k)));
      if (inner) {
        for (int i = 0; i < kRoomsN; ++i) {
          const double door_mid = (i + 0.5) * kCellM;
          p->push_back(make(door_mid - 0.5 * kDoorM, door_mid + 0.5 * kDoorM, 0.4 * kWallM,
                            kDoorHeightM, kHeightM, line + "_lintel" + std::to_string(i)));
        }
      }
    }
  }
}

// Room (rx, ry)'s boxes: two or three of its corners each get one, sometimes with a smaller one on
// top.
void add_room_boxes(int rx, int ry, detail::HashRng* rng, std::vector<Primitive>* p) {
  using namespace rooms_layout;
  const double hw = 0.5 * kWallM;
  const int count = rng->uniform_int(2, 3);
  const int skip = rng->uniform_int(0, 3);  // the corner left free when there are three boxes
  int placed = 0;
  for (int corner = 0; corner < 4 && placed < count; ++corner) {
    if (count == 3 && corner == skip) continue;
    if (count == 2 && (corner == skip || corner == (skip + 2) % 4)) continue;
    const int sx = corner & 1, sy = corner >> 1;
    const double w = rng->uniform(0.4, 1.0), d = rng->uniform(0.4, 1.0),
                 h = rng->uniform(0.3, 1.2);
    const double gx = rng->uniform(0.1, 0.3), gy = rng->uniform(0.1, 0.3);
    const double x0 = sx == 0 ? rx * kCellM + hw + gx : (rx + 1) * kCellM - hw - gx - w;
    const double y0 = sy == 0 ? ry * kCellM + hw + gy : (ry + 1) * kCellM - hw - gy - d;
    const std::string name =
        "box_r" + std::to_string(rx) + std::to_string(ry) + "_c" + std::to_string(corner);
    p->push_back(random_colored(
        Primitive::box(Vector3d(x0, y0, 0.0), Vector3d(x0 + w, y0 + d, h), name), rng));
    if (rng->uniform() < 0.35) {
      const double tw = w * rng->uniform(0.4, 0.7), td = d * rng->uniform(0.4, 0.7);
      const double tx = x0 + rng->uniform(0.1, 0.9) * (w - tw);
      const double ty = y0 + rng->uniform(0.1, 0.9) * (d - td);
      const double th = rng->uniform(0.2, 0.5);
      p->push_back(
          random_colored(Primitive::box(Vector3d(tx, ty, h), Vector3d(tx + tw, ty + td, h + th),
                                        name + "_top"),
                         rng));
    }
    ++placed;
  }
}

// 4 x 4 rooms of 5 x 5 m. Boxes sit in room corners, at most 1.3 m from the walls: the walk of
// trajectory.cpp goes straight through room centres or on quarter circles of radius 2.5 m around a
// room corner, which keeps >= 0.6 m from every box.
std::vector<Primitive> make_rooms(uint64_t seed) {
  using namespace rooms_layout;
  detail::HashRng rng(detail::stream_key(seed, detail::kStreamSceneLayout, 2));
  std::vector<Primitive> p;
  add_rooms_floor_and_ceiling(&p);
  add_rooms_walls(&p);
  for (int ry = 0; ry < kRoomsN; ++ry)
    for (int rx = 0; rx < kRoomsN; ++rx) add_room_boxes(rx, ry, &rng, &p);
  return p;
}

}  // namespace

Scene Scene::make(SceneKind kind, uint64_t seed) {
  std::vector<Primitive> primitives;
  switch (kind) {
    case SceneKind::kCorner:
      primitives = make_corner();
      break;
    case SceneKind::kRoom:
      primitives = make_room(seed);
      break;
    case SceneKind::kRooms:
      primitives = make_rooms(seed);
      break;
    case SceneKind::kFurnished:
      primitives = lap_rooms::make_furnished(seed);
      break;
    case SceneKind::kPlain:
      primitives = lap_rooms::make_plain(seed);
      break;
  }
  Result<Scene> scene = create(std::move(primitives), to_string(kind));
  // The built-in layouts are valid by construction; a failure here is a bug caught by the tests.
  return scene.is_ok() ? std::move(scene).value() : Scene();
}

}  // namespace depthfuse::synthetic
