// Internal: the furnished and the plain room and the handheld walk of laps around their middle.
// The builders (scene_furnished.cpp) keep their furniture clear of the region the walk
// (lap_walk.cpp) moves the camera through; both take that region from here.
#pragma once

#include <cstddef>
#include <cstdint>
#include <vector>

#include "depthfuse/synthetic/scene.hpp"
#include "depthfuse/types.hpp"

namespace depthfuse::synthetic::lap_rooms {

// The room: [0, kRoomXM] x [0, kRoomYM] x [0, kHeightM].
constexpr double kRoomXM = 5.0;
constexpr double kRoomYM = 4.0;
constexpr double kHeightM = 2.6;

// The walk: a loop around (kCentreXM, kCentreYM), a little north of the room's middle, whose
// semi-axes vary about kSemiXM and kSemiYM from lap to lap (by up to 6 cm, the centre by up to
// 5 cm): every camera position lies within x in [1.7, 3.3], y in [1.6, 3.0], 1.3-1.5 m high. On
// its north side the camera passes 0.8 m from the sofa's back, near enough that the sofa alone
// fills the view for a second or two.
constexpr double kCentreXM = 2.5;
constexpr double kCentreYM = 2.3;
constexpr double kSemiXM = 0.65;
constexpr double kSemiYM = 0.58;

// A 5 x 4 x 2.6 m living room: a sofa along the north wall (y = 4), a bookshelf with books on the
// west wall, a door and a desk with a monitor on the south wall, a cabinet with a lamp on the east
// wall, a side table, a floor lamp and three pictures; jittered by the seed. Walls, ceiling and
// the large furniture are one plain colour each; the floor, books and pictures are textured.
std::vector<Primitive> make_furnished(uint64_t seed);
// The same room with nothing but one low box near a wall.
std::vector<Primitive> make_plain(uint64_t seed);

// Frame i of the walk at rate_hz (a closed-form function of the time i / rate_hz).
Pose lap_walk_pose(size_t i, double rate_hz);

}  // namespace depthfuse::synthetic::lap_rooms
