// Internal: the pieces the built-in scenes are made of (scene_make.cpp, scene_furnished.cpp).
#pragma once

#include <Eigen/Geometry>
#include <cstdint>
#include <string>
#include <utility>

#include "depthfuse/synthetic/scene.hpp"
#include "random.hpp"

namespace depthfuse::synthetic::scene_parts {

inline Primitive colored(Primitive p, uint8_t r, uint8_t g, uint8_t b) {
  p.color_rgb = {r, g, b};
  return p;
}

// A box colour from the layout generator: saturated, never too dark for the colour image.
inline Primitive random_colored(Primitive p, detail::HashRng* rng) {
  return colored(std::move(p), static_cast<uint8_t>(rng->uniform_int(90, 240)),
                 static_cast<uint8_t>(rng->uniform_int(90, 240)),
                 static_cast<uint8_t>(rng->uniform_int(90, 240)));
}

// A box of nominal footprint [x0,x1] x [y0,y1] and height h on z0, jittered by the seed: the
// position by up to +-jitter_m (not past `limit`), each size by up to +-15 %.
inline Primitive jittered_box(detail::HashRng* rng, double x0, double x1, double y0, double y1,
                              double z0, double h, double jitter_m,
                              const Eigen::AlignedBox2d& limit, std::string name) {
  const double sx = (x1 - x0) * rng->uniform(0.85, 1.15);
  const double sy = (y1 - y0) * rng->uniform(0.85, 1.15);
  const double sz = h * rng->uniform(0.85, 1.15);
  double cx = 0.5 * (x0 + x1) + rng->uniform(-jitter_m, jitter_m);
  double cy = 0.5 * (y0 + y1) + rng->uniform(-jitter_m, jitter_m);
  cx = std::fmin(std::fmax(cx, limit.min().x() + 0.5 * sx), limit.max().x() - 0.5 * sx);
  cy = std::fmin(std::fmax(cy, limit.min().y() + 0.5 * sy), limit.max().y() - 0.5 * sy);
  return random_colored(
      Primitive::box(Eigen::Vector3d(cx - 0.5 * sx, cy - 0.5 * sy, z0),
                     Eigen::Vector3d(cx + 0.5 * sx, cy + 0.5 * sy, z0 + sz), std::move(name)),
      rng);
}

}  // namespace depthfuse::synthetic::scene_parts
