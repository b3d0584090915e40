// Writes a synthetic sequence as a TUM RGB-D style folder, readable like recorded data:
//   depth/<timestamp>.png   16-bit PNG, value = depth_m * 5000 (TUM convention), 0 = no depth
//   rgb/<timestamp>.png     8-bit colour registered to depth (only with_color)
//   depth.txt, rgb.txt      "# ..." header lines, then "timestamp path" per frame
//   groundtruth.txt         true poses, "timestamp tx ty tz qx qy qz qw", camera to world
//   poses_perturbed.txt     the perturbed poses, same format (equal to the truth without noise)
//   camera.toml             [camera] width, height, fx, fy, cx, cy, depth_scale
//   scene.toml              Scene::to_toml() plus a [generator] table with the settings
//   README.txt              what all this is
// Timestamps are seconds with 6 decimals (frame i at i / rate_hz).
#pragma once

#include <string>

#include "depthfuse/status.hpp"
#include "depthfuse/synthetic/synthetic_sequence.hpp"

namespace depthfuse::synthetic {

constexpr double kTumDepthScale = 5000.0;  // PNG value per metre

// "12.345678": the file name stem and the timestamp column for a utime.
std::string tum_timestamp(int64_t utime);

// Creates `folder` (and parents) if needed and writes every frame (with noise). Errors name the
// path that failed.
Status write_tum_folder(const SyntheticSequence& sequence, const std::string& folder,
                        bool with_color = true);

}  // namespace depthfuse::synthetic
