#include "decoder_scene.hpp"

#include <algorithm>
#include <cmath>
#include <cstdint>

namespace depthfuse::kinect2::test {

SceneImages scene_images(int variant) {
  SceneImages scene;
  scene.depth = DepthImage(kRawWidth, kRawHeight);
  scene.ir.width = kRawWidth;
  scene.ir.height = kRawHeight;
  scene.ir.amplitude.assign(kRawPixels, 0.0f);
  const double shift = variant * 3.0;
  for (int v = 0; v < kRawHeight; ++v) {
    for (int u = 0; u < kRawWidth; ++u) {
      // A slanted back wall, a box in front (sharp edges), a sphere, a far strip and a near strip.
      double depth = 3.2 + 0.8 * u / kRawWidth + 0.3 * v / kRawHeight;
      double albedo = 0.6 + 0.3 * std::sin(u / 9.0) * std::cos(v / 13.0);
      if (u > 60 + shift && u < 200 + shift && v > 80 && v < 300) {
        depth = 1.3 + 0.001 * (u - 60);
        albedo = 0.9;
      }
      const double du = u - (360 - shift), dv = v - 200;
      if (du * du + dv * dv < 70.0 * 70.0)
        depth = 2.0 - 0.5 * std::sqrt(1.0 - (du * du + dv * dv) / (70.0 * 70.0));
      if (v > 380) depth = 5.0 + 0.01 * (v - 380);  // beyond max_depth
      if (u > 440 && v < 40) depth = 0.35;           // nearer than min_depth
      if (u > 20 && u < 40 && v > 20 && v < 60) albedo = 0.002;  // too weak to measure
      if (u > 100 && u < 300 && v > 320 && v < 376) {
        // Ever weaker towards the left, with jittered depth: the phases of the three frequencies
        // disagree more and more, until unwrapping is refused.
        albedo = 0.0005 + 0.03 * (u - 100) / 200.0;
        const uint32_t hash = static_cast<uint32_t>(u * 73856093) ^ static_cast<uint32_t>(v * 19349663);
        depth += 0.02 * ((hash % 1000) / 1000.0 - 0.5);
      }
      float ir = static_cast<float>(std::min(60000.0, 9000.0 * albedo / (depth * depth) * 4.0));
      if (u > 480 && v > 200 && v < 230) ir = 65535.0f;  // saturated
      scene.depth.at(u, v) = static_cast<float>(depth);
      scene.ir.amplitude[static_cast<size_t>(v) * kRawWidth + u] = ir;
    }
  }
  return scene;
}

}  // namespace depthfuse::kinect2::test
