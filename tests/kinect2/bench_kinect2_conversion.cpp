// Per-frame cost of what the driver does on top of libfreenect2's depth decoding: registration
// (undistortion + colour mapping) and the conversions to depthfuse images. Frames built in memory.
//   build-*/bin/bench_kinect2_conversion
#include <cstring>

#include <benchmark/benchmark.h>
#include <libfreenect2/registration.h>

#include "depthfuse/kinect2/conversion.hpp"

namespace depthfuse::kinect2 {
namespace {

libfreenect2::Freenect2Device::IrCameraParams ir_params() {
  libfreenect2::Freenect2Device::IrCameraParams ir{};
  ir.fx = 365.5f;
  ir.fy = 365.5f;
  ir.cx = 257.8f;
  ir.cy = 206.5f;
  ir.k1 = 0.0905f;
  ir.k2 = -0.2683f;
  ir.k3 = 0.0950f;
  return ir;
}

libfreenect2::Freenect2Device::ColorCameraParams color_params() {
  libfreenect2::Freenect2Device::ColorCameraParams c{};
  c.fx = 1081.37f;
  c.fy = 1081.37f;
  c.cx = 959.5f;
  c.cy = 539.5f;
  c.shift_d = 863.0f;
  c.shift_m = 52.0f;
  c.mx_x1y0 = 0.2199f * 0.33f;
  c.my_x0y1 = 0.2199f * 0.33f;
  return c;
}

void fill_depth(libfreenect2::Frame& depth) {
  for (size_t i = 0; i < depth.width * depth.height; ++i) {
    const float mm = 800.0f + static_cast<float>(i % 2000);
    std::memcpy(depth.data + 4 * i, &mm, 4);
  }
}

void BM_ConvertDepth(benchmark::State& state) {
  libfreenect2::Frame depth(kDepthWidth, kDepthHeight, 4);
  fill_depth(depth);
  DepthImage out;
  for (auto _ : state) {
    benchmark::DoNotOptimize(convert_depth_frame(depth, &out));
    benchmark::ClobberMemory();
  }
}
BENCHMARK(BM_ConvertDepth)->Unit(benchmark::kMicrosecond);

void BM_ConvertRegisteredColor(benchmark::State& state) {
  libfreenect2::Frame registered(kDepthWidth, kDepthHeight, 4);
  std::memset(registered.data, 0x5a, registered.width * registered.height * 4);
  ColorImage out;
  for (auto _ : state) {
    benchmark::DoNotOptimize(convert_registered_color(registered, libfreenect2::Frame::BGRX, &out));
    benchmark::ClobberMemory();
  }
}
BENCHMARK(BM_ConvertRegisteredColor)->Unit(benchmark::kMicrosecond);

void BM_RegisterAndConvert(benchmark::State& state) {
  libfreenect2::Registration registration(ir_params(), color_params());
  libfreenect2::Frame depth(kDepthWidth, kDepthHeight, 4);
  fill_depth(depth);
  libfreenect2::Frame rgb(kColorWidth, kColorHeight, 4);
  rgb.format = libfreenect2::Frame::BGRX;
  std::memset(rgb.data, 0x7f, rgb.width * rgb.height * 4);
  libfreenect2::Frame undistorted(kDepthWidth, kDepthHeight, 4);
  libfreenect2::Frame registered(kDepthWidth, kDepthHeight, 4);
  DepthImage depth_m;
  ColorImage color;
  for (auto _ : state) {
    registration.apply(&rgb, &depth, &undistorted, &registered, true);
    benchmark::DoNotOptimize(convert_depth_frame(undistorted, &depth_m));
    benchmark::DoNotOptimize(convert_registered_color(registered, rgb.format, &color));
    benchmark::ClobberMemory();
  }
}
BENCHMARK(BM_RegisterAndConvert)->Unit(benchmark::kMillisecond);

}  // namespace
}  // namespace depthfuse::kinect2

BENCHMARK_MAIN();
