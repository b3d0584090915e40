#include "decoder_tables.hpp"

#include <cmath>
#include <limits>

namespace depthfuse::kinect2 {

namespace {

// Brown-Conrady distortion of normalised coordinates.
void distort(const IrCalibration& c, double x, double y, double* xd, double* yd) {
  const double x2 = x * x, y2 = y * y, r2 = x2 + y2, xy = x * y;
  const double radial = ((c.k3 * r2 + c.k2) * r2 + c.k1) * r2 + 1.0;
  *xd = x * radial + c.p2 * (r2 + 2 * x2) + 2 * c.p1 * xy;
  *yd = y * radial + c.p1 * (r2 + 2 * y2) + 2 * c.p2 * xy;
}

}  // namespace

void undistort_normalised(const IrCalibration& c, double xd, double yd, double* xu, double* yu) {
  double x = xd, y = yd;
  const double eps = std::numeric_limits<double>::epsilon() * 16;
  for (int iteration = 0; iteration < 100; ++iteration) {
    const double x2 = x * x, y2 = y * y, r2 = x2 + y2, r4 = r2 * r2, r6 = r2 * r4;
    const double dxdx = c.k3 * r6 + (c.k2 + 6 * c.k3 * x2) * r4 + (c.k1 + 4 * c.k2 * x2) * r2 +
                        2 * c.k1 * x2 + 6 * c.p2 * x + 2 * c.p1 * y + 1;
    const double dxdy = 6 * c.k3 * x * y * r4 + 4 * c.k2 * x * y * r2 + 2 * c.k1 * x * y +
                        2 * c.p1 * x + 2 * c.p2 * y;
    const double dydy = c.k3 * r6 + (c.k2 + 6 * c.k3 * y2) * r4 + (c.k1 + 4 * c.k2 * y2) * r2 +
                        2 * c.k1 * y2 + 2 * c.p2 * x + 6 * c.p1 * y + 1;
    const double inverse_det = 1 / (dxdx * dydy - dxdy * dxdy);
    double fx, fy;
    distort(c, x, y, &fx, &fy);
    fx -= xd;
    fy -= yd;
    const double step_x = (dydy * fx - dxdy * fy) * inverse_det;
    const double step_y = (-dxdy * fx + dxdx * fy) * inverse_det;
    x -= step_x;
    y -= step_y;
    if (std::fabs(step_x) <= eps && std::fabs(step_y) <= eps) break;
  }
  *xu = x;
  *yu = y;
}

float p0_phase_rad(uint16_t p0) {
  // The firmware's scale: 0.000031 pi radians per unit (in double, rounded to float).
  return static_cast<float>(-static_cast<double>(static_cast<float>(p0)) * 0.000031 * M_PI);
}

RayTables make_ray_tables(const IrCalibration& calibration) {
  const double unambiguous_mm = 6250.0 / 3;
  RayTables tables;
  tables.z_mm_per_phase.resize(kRawPixels);
  tables.x_scaled.resize(kRawPixels);
  for (size_t i = 0; i < kRawPixels; ++i) {
    const double xd = (static_cast<double>(i % kRawWidth) + 0.5 - calibration.cx) / calibration.fx;
    const double yd = (static_cast<double>(i / kRawWidth) + 0.5 - calibration.cy) / calibration.fy;
    double xu, yu;
    undistort_normalised(calibration, xd, yd, &xu, &yu);
    tables.x_scaled[i] = static_cast<float>(8192 * xu);
    tables.z_mm_per_phase[i] = static_cast<float>(unambiguous_mm / std::sqrt(xu * xu + yu * yu + 1));
  }
  return tables;
}

PhaseTables make_phase_tables(const P0Tables& p0, const DecodeConstants& constants) {
  PhaseTables tables;
  for (int k = 0; k < 3; ++k) {
    tables.cos_step[k] = std::cos(constants.phase_in_rad[k]);
    tables.sin_step[k] = std::sin(constants.phase_in_rad[k]);
  }
  for (int f = 0; f < 3; ++f) {
    tables.cos_p0[f].resize(kRawPixels);
    tables.sin_p0[f].resize(kRawPixels);
    for (int y = 0; y < kRawHeight; ++y) {
      for (int x = 0; x < kRawWidth; ++x) {
        const float offset = p0_phase_rad(p0_at(p0, f, x, y));
        const size_t i = static_cast<size_t>(y) * kRawWidth + x;
        tables.cos_p0[f][i] = std::cos(offset);
        tables.sin_p0[f][i] = std::sin(offset);
      }
    }
  }
  return tables;
}

}  // namespace depthfuse::kinect2
