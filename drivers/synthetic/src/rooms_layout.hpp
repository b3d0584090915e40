// Geometry of the "rooms" scene shared by its generator (scene_make.cpp) and its walk
// (trajectory.cpp): a kRoomsN x kRoomsN grid of kCellM rooms, walls kWallM thick centred on the
// grid lines, doorways kDoorM wide in the middle of every inner wall, kDoorHeightM high.
#pragma once

namespace depthfuse::synthetic::rooms_layout {

constexpr int kRoomsN = 4;
constexpr double kCellM = 5.0;
constexpr double kWallM = 0.1;
constexpr double kDoorM = 1.2;
constexpr double kHeightM = 2.6;
constexpr double kDoorHeightM = 2.1;

}  // namespace depthfuse::synthetic::rooms_layout
