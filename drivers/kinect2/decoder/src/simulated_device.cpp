#include "depthfuse/kinect2/simulated_device.hpp"

#include <cmath>
#include <cstdint>

namespace depthfuse::kinect2 {

P0Tables simulated_p0_tables() {
  // Values near those a device reports (each table's border value), varying smoothly.
  const int base[3] = {0x2c9a, 0x08ec, 0x42e8};
  P0Tables tables;
  for (int f = 0; f < 3; ++f) {
    tables.table[f].resize(kRawPixels);
    for (int y = 0; y < kRawHeight; ++y)
      for (int x = 0; x < kRawWidth; ++x) {
        const double variation = 900.0 * std::sin(x / 70.0 + f) * std::cos(y / 55.0 - f) +
                                 300.0 * std::sin((x + y) / 23.0);
        tables.table[f][static_cast<size_t>(y) * kRawWidth + x] =
            static_cast<uint16_t>(base[f] + static_cast<int>(variation));
      }
  }
  return tables;
}

IrCalibration simulated_ir_calibration() {
  IrCalibration c;
  c.fx = 365.481f;
  c.fy = 365.481f;
  c.cx = 257.346f;
  c.cy = 210.347f;
  c.k1 = 0.0905474f;
  c.k2 = -0.26819f;
  c.k3 = 0.0950862f;
  return c;
}

}  // namespace depthfuse::kinect2
