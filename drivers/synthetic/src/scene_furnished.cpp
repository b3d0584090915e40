// The furnished and the plain room of the lap walk. Everything stands against a wall, clear of the
// walk's region (lap_rooms.hpp): the sofa's front by 0.1 m in x-y and 0.85 m below the camera,
// the rest by 0.8 m or more, so the camera (1.3-1.5 m high) stays 0.5 m or more from every
// surface.
//
// What the tracker should find hard, as a real room makes it: the sofa is long and plain and the
// wall above it bare, so a view of it has normals across it (seat, front, back, wall, floor) and
// none along it; the walls and the sofa have no texture in the colour image either.
#include <cmath>
#include <string>
#include <utility>
#include <vector>

#include "lap_rooms.hpp"
#include "random.hpp"
#include "scene_parts.hpp"

namespace depthfuse::synthetic::lap_rooms {

namespace {

using Eigen::Vector3d;
using scene_parts::colored;
using scene_parts::random_colored;

// A box in one plain colour.
Primitive plain_box(const Vector3d& lo, const Vector3d& hi, std::string name, uint8_t r, uint8_t g,
                    uint8_t b) {
  Primitive p = colored(Primitive::box(lo, hi, std::move(name)), r, g, b);
  p.checker_m = 0.0;
  return p;
}

// Floor, ceiling and four walls as planes (each its own colour and texture), normals into the
// room. Each rectangle reaches 1 cm past the room's edges, behind its neighbours, so that a ray
// along a seam hits one of them.
void add_shell(std::vector<Primitive>* p, bool textured_floor) {
  constexpr double e = 0.01;
  const double X = kRoomXM, Y = kRoomYM, Z = kHeightM;
  Primitive floor = colored(Primitive::plane(Vector3d::Zero(), Vector3d::UnitZ(), Vector3d::UnitX(),
                                             -e, X + e, -e, Y + e, "floor"),
                            150, 118, 84);
  floor.checker_m = textured_floor ? 0.3 : 0.0;  // parquet, or a plain carpet
  p->push_back(floor);
  auto wall = [&](Primitive q) {
    q.checker_m = 0.0;  // painted
    p->push_back(colored(std::move(q), 226, 221, 208));
  };
  // Ceiling facing down: u = +y, v = n x u = +x.
  Primitive ceiling = Primitive::plane(Vector3d(0, 0, Z), -Vector3d::UnitZ(), Vector3d::UnitY(), -e,
                                       Y + e, -e, X + e, "ceiling");
  ceiling.checker_m = 0.0;
  p->push_back(colored(std::move(ceiling), 240, 240, 236));
  // x = 0: u = +y, v = +z.  x = X: u = +z, v = +y.  y = 0: u = +z, v = +x.  y = Y: u = +x, v = +z.
  wall(Primitive::plane(Vector3d::Zero(), Vector3d::UnitX(), Vector3d::UnitY(), -e, Y + e, -e,
                        Z + e, "wall_west"));
  wall(Primitive::plane(Vector3d(X, 0, 0), -Vector3d::UnitX(), Vector3d::UnitZ(), -e, Z + e, -e,
                        Y + e, "wall_east"));
  wall(Primitive::plane(Vector3d::Zero(), Vector3d::UnitY(), Vector3d::UnitZ(), -e, Z + e, -e,
                        X + e, "wall_south"));
  wall(Primitive::plane(Vector3d(0, Y, 0), -Vector3d::UnitY(), Vector3d::UnitX(), -e, X + e, -e,
                        Z + e, "wall_north"));
}

// The sofa against the north wall, 5 cm off it: a seat, a back the whole length and two arms.
// Its long axis is x.
void add_sofa(std::vector<Primitive>* p, detail::HashRng* rng) {
  const double length = 2.3 * rng->uniform(0.97, 1.03);
  const double cx = 2.45 + rng->uniform(-0.12, 0.12);
  const double x0 = cx - 0.5 * length, x1 = cx + 0.5 * length;
  const double y_front = kRoomYM - 0.9, y_back = kRoomYM - 0.05, y_seat_end = y_back - 0.2;
  const double arm = 0.2, seat_h = 0.42 + rng->uniform(-0.02, 0.02);
  const double back_h = 0.86 + rng->uniform(-0.03, 0.03), arm_h = 0.62;
  const uint8_t r = static_cast<uint8_t>(rng->uniform_int(70, 110));
  const uint8_t g = static_cast<uint8_t>(rng->uniform_int(90, 120));
  const uint8_t b = static_cast<uint8_t>(rng->uniform_int(110, 150));
  p->push_back(plain_box(Vector3d(x0 + arm, y_front, 0), Vector3d(x1 - arm, y_seat_end, seat_h),
                         "sofa_seat", r, g, b));
  p->push_back(
      plain_box(Vector3d(x0, y_seat_end, 0), Vector3d(x1, y_back, back_h), "sofa_back", r, g, b));
  p->push_back(plain_box(Vector3d(x0, y_front, 0), Vector3d(x0 + arm, y_seat_end, arm_h),
                         "sofa_arm_west", r, g, b));
  p->push_back(plain_box(Vector3d(x1 - arm, y_front, 0), Vector3d(x1, y_seat_end, arm_h),
                         "sofa_arm_east", r, g, b));
}

// A bookshelf against the west wall: sides, top, back, a plinth and four shelves, with rows of
// books of random sizes and colours (some gaps, some shelves half full).
void add_bookshelf(std::vector<Primitive>* p, detail::HashRng* rng) {
  const double y0 = 0.35 + rng->uniform(-0.05, 0.05), width = 0.9, depth = 0.35, h = 2.0;
  const double x0 = 0.02, x1 = x0 + depth, y1 = y0 + width, board = 0.02;
  constexpr uint8_t kWood[3] = {196, 170, 130};
  auto part = [&](const Vector3d& lo, const Vector3d& hi, const std::string& name) {
    p->push_back(plain_box(lo, hi, "shelf_" + name, kWood[0], kWood[1], kWood[2]));
  };
  part(Vector3d(x0, y0, 0), Vector3d(x1, y0 + board, h), "side_south");
  part(Vector3d(x0, y1 - board, 0), Vector3d(x1, y1, h), "side_north");
  part(Vector3d(x0, y0 + board, h - board), Vector3d(x1, y1 - board, h), "top");
  part(Vector3d(x0, y0 + board, 0), Vector3d(x0 + 0.015, y1 - board, h - board), "back");
  part(Vector3d(x0 + 0.015, y0 + board, 0), Vector3d(x1 - 0.02, y1 - board, 0.08), "plinth");
  const double levels[] = {0.08, 0.46, 0.84, 1.22, 1.60};  // what each row of books stands on
  for (size_t k = 0; k < 5; ++k) {
    const double z = levels[k];
    if (k > 0)
      part(Vector3d(x0 + 0.015, y0 + board, z - board), Vector3d(x1, y1 - board, z),
           "board" + std::to_string(k));
    const double fill = rng->uniform(0.45, 0.95);  // how much of the row holds books
    double y = y0 + board + rng->uniform(0.0, 0.06);
    int n = 0;
    while (y < y0 + board + fill * (width - 2 * board)) {
      const double w = rng->uniform(0.02, 0.055), bh = rng->uniform(0.17, 0.32);
      const double bd = rng->uniform(0.15, 0.25);
      if (y + w > y1 - board) break;
      p->push_back(random_colored(
          Primitive::box(Vector3d(x0 + 0.015, y, z), Vector3d(x0 + 0.015 + bd, y + w, z + bh),
                         "book" + std::to_string(k) + "_" + std::to_string(n++)),
          rng));
      p->back().checker_m = 0.0;
      y += w + (rng->uniform() < 0.15 ? rng->uniform(0.02, 0.08) : 0.0);
    }
  }
}

// A picture on a wall: a thin box `proud_m` off the wall at x = wall_x (normal +-x) or y = wall_y.
Primitive picture(detail::HashRng* rng, int axis, double wall, double inward, double a0, double a1,
                  double z0, double z1, const std::string& name) {
  const double proud = rng->uniform(0.02, 0.04);
  Vector3d lo, hi;
  const double w0 = inward > 0 ? wall : wall - proud, w1 = inward > 0 ? wall + proud : wall;
  if (axis == 0) {
    lo = Vector3d(w0, a0, z0);
    hi = Vector3d(w1, a1, z1);
  } else {
    lo = Vector3d(a0, w0, z0);
    hi = Vector3d(a1, w1, z1);
  }
  Primitive q = random_colored(Primitive::box(lo, hi, name), rng);
  q.checker_m = 0.04;  // the picture's content
  return q;
}

// The door on the south wall: a leaf 1 cm proud of it in a frame 2 cm proud, and a handle.
void add_door(std::vector<Primitive>* p) {
  const double x0 = 1.0, x1 = 1.85, top = 2.0, frame = 0.07;
  auto part = [&](const Vector3d& lo, const Vector3d& hi, const std::string& name, uint8_t grey) {
    p->push_back(plain_box(lo, hi, name, grey, grey, static_cast<uint8_t>(grey - 8)));
  };
  part(Vector3d(x0, 0, 0), Vector3d(x1, 0.01, top), "door_leaf", 236);
  part(Vector3d(x0 - frame, 0, 0), Vector3d(x0, 0.02, top + frame), "door_frame_west", 246);
  part(Vector3d(x1, 0, 0), Vector3d(x1 + frame, 0.02, top + frame), "door_frame_east", 246);
  part(Vector3d(x0, 0, top), Vector3d(x1, 0.02, top + frame), "door_frame_top", 246);
  part(Vector3d(x1 - 0.14, 0.01, 0.98), Vector3d(x1 - 0.02, 0.06, 1.02), "door_handle", 120);
}

// The desk against the south wall: a top on two side panels, a modesty panel, a monitor on a
// stand.
void add_desk(std::vector<Primitive>* p, detail::HashRng* rng) {
  const double x0 = 3.05 + rng->uniform(-0.1, 0.1), x1 = x0 + 1.4;
  const double y0 = 0.02, y1 = 0.72, top = 0.75;
  constexpr uint8_t kDesk[3] = {210, 205, 195};
  auto part = [&](const Vector3d& lo, const Vector3d& hi, const std::string& name) {
    p->push_back(plain_box(lo, hi, name, kDesk[0], kDesk[1], kDesk[2]));
  };
  part(Vector3d(x0, y0, top - 0.03), Vector3d(x1, y1, top), "desk_top");
  part(Vector3d(x0, y0, 0), Vector3d(x0 + 0.03, y1, top - 0.03), "desk_side_west");
  part(Vector3d(x1 - 0.03, y0, 0), Vector3d(x1, y1, top - 0.03), "desk_side_east");
  part(Vector3d(x0 + 0.03, y0 + 0.03, 0.3), Vector3d(x1 - 0.03, y0 + 0.05, top - 0.03),
       "desk_modesty");
  const double mx = 0.5 * (x0 + x1) + rng->uniform(-0.2, 0.2);
  p->push_back(plain_box(Vector3d(mx - 0.04, 0.14, top), Vector3d(mx + 0.04, 0.22, top + 0.1),
                         "monitor_stand", 40, 40, 44));
  p->push_back(plain_box(Vector3d(mx - 0.28, 0.16, top + 0.1),
                         Vector3d(mx + 0.28, 0.19, top + 0.44), "monitor", 30, 30, 34));
}

// The cabinet against the east wall with a table lamp on it.
void add_cabinet(std::vector<Primitive>* p, detail::HashRng* rng) {
  const double y0 = 1.55 + rng->uniform(-0.08, 0.08), y1 = y0 + 0.9;
  const double x0 = kRoomXM - 0.47, x1 = kRoomXM - 0.02, h = 0.9 * rng->uniform(0.95, 1.05);
  p->push_back(plain_box(Vector3d(x0, y0, 0), Vector3d(x1, y1, h), "cabinet", 120, 84, 60));
  const double ly = y0 + 0.25;
  p->push_back(plain_box(Vector3d(x0 + 0.15, ly - 0.06, h), Vector3d(x0 + 0.27, ly + 0.06, h + 0.32),
                         "lamp_base", 200, 200, 190));
  p->push_back(plain_box(Vector3d(x0 + 0.07, ly - 0.14, h + 0.32),
                         Vector3d(x0 + 0.35, ly + 0.14, h + 0.52), "lamp_shade", 245, 235, 205));
}

// A low side table west of the sofa and a floor lamp in the north-east corner.
void add_side_table_and_floor_lamp(std::vector<Primitive>* p, detail::HashRng* rng) {
  const double x0 = 0.55 + rng->uniform(-0.05, 0.05), x1 = x0 + 0.5;
  const double y0 = kRoomYM - 0.7, y1 = y0 + 0.5, h = 0.5;
  constexpr uint8_t kWood[3] = {160, 120, 80};
  auto part = [&](const Vector3d& lo, const Vector3d& hi, const std::string& name) {
    p->push_back(plain_box(lo, hi, name, kWood[0], kWood[1], kWood[2]));
  };
  part(Vector3d(x0, y0, h - 0.03), Vector3d(x1, y1, h), "side_table_top");
  const double leg = 0.04;
  for (int k = 0; k < 4; ++k) {
    const double lx = (k & 1) ? x1 - leg - 0.02 : x0 + 0.02;
    const double ly = (k & 2) ? y1 - leg - 0.02 : y0 + 0.02;
    part(Vector3d(lx, ly, 0), Vector3d(lx + leg, ly + leg, h - 0.03),
         "side_table_leg" + std::to_string(k));
  }
  const double fx = kRoomXM - 0.4, fy = kRoomYM - 0.4;
  p->push_back(plain_box(Vector3d(fx - 0.15, fy - 0.15, 0), Vector3d(fx + 0.15, fy + 0.15, 0.03),
                         "floor_lamp_base", 50, 50, 50));
  p->push_back(plain_box(Vector3d(fx - 0.015, fy - 0.015, 0.03),
                         Vector3d(fx + 0.015, fy + 0.015, 1.55), "floor_lamp_pole", 50, 50, 50));
  p->push_back(plain_box(Vector3d(fx - 0.17, fy - 0.17, 1.55), Vector3d(fx + 0.17, fy + 0.17, 1.8),
                         "floor_lamp_shade", 240, 228, 200));
}

}  // namespace

std::vector<Primitive> make_furnished(uint64_t seed) {
  detail::HashRng rng(detail::stream_key(seed, detail::kStreamSceneLayout, 3));
  std::vector<Primitive> p;
  add_shell(&p, true);
  add_sofa(&p, &rng);
  add_bookshelf(&p, &rng);
  add_door(&p);
  add_desk(&p, &rng);
  add_cabinet(&p, &rng);
  add_side_table_and_floor_lamp(&p, &rng);
  // Pictures: between the door and the desk, on the west wall north of the bookshelf, on the east
  // wall north of the cabinet. None above the sofa.
  const double z = 1.3 + rng.uniform(-0.05, 0.05);
  p.push_back(picture(&rng, 1, 0.0, 1.0, 2.2, 2.8, z, z + 0.45, "picture_south"));
  p.push_back(picture(&rng, 0, 0.0, 1.0, 2.0, 2.7, z + 0.05, z + 0.55, "picture_west"));
  p.push_back(picture(&rng, 0, kRoomXM, -1.0, 2.75, 3.35, z - 0.05, z + 0.4, "picture_east"));
  return p;
}

std::vector<Primitive> make_plain(uint64_t seed) {
  detail::HashRng rng(detail::stream_key(seed, detail::kStreamSceneLayout, 4));
  std::vector<Primitive> p;
  add_shell(&p, false);
  // One low box (a chest) against the south wall, somewhere along it.
  const double x0 = rng.uniform(0.4, 3.8), w = rng.uniform(0.6, 0.9);
  p.push_back(plain_box(Vector3d(x0, 0.02, 0), Vector3d(x0 + w, 0.47, rng.uniform(0.35, 0.45)),
                        "chest", 130, 100, 80));
  return p;
}

}  // namespace depthfuse::synthetic::lap_rooms
