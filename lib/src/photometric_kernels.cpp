#include "photometric_kernels.hpp"

namespace depthfuse {

void build_intensity_pyramid(const ColorImage& color, int levels, std::vector<IntensityLevel>* out) {
  out->resize(static_cast<size_t>(std::max(1, levels)));
  IntensityLevel& base = (*out)[0];
  base.width = color.width;
  base.height = color.height;
  const size_t n = static_cast<size_t>(color.width) * color.height;
  base.intensity.resize(n);
  const uint8_t* rgb = color.rgb.data();
  float* I = base.intensity.data();
  constexpr float kR = 0.299f / 255, kG = 0.587f / 255, kB = 0.114f / 255;
  DF_IVDEP
  for (size_t i = 0; i < n; ++i) I[i] = kR * rgb[3 * i] + kG * rgb[3 * i + 1] + kB * rgb[3 * i + 2];
  for (size_t l = 1; l < out->size(); ++l) {
    const IntensityLevel& fine = (*out)[l - 1];
    IntensityLevel& coarse = (*out)[l];
    coarse.width = std::max(1, fine.width / 2);
    coarse.height = std::max(1, fine.height / 2);
    coarse.intensity.resize(static_cast<size_t>(coarse.width) * coarse.height);
    for (int v = 0; v < coarse.height; ++v) {
      // A level of odd size loses its last row or column; a 1-pixel level repeats its pixel.
      const float* a = fine.intensity.data() + static_cast<size_t>(std::min(2 * v, fine.height - 1)) * fine.width;
      const float* b = fine.intensity.data() + static_cast<size_t>(std::min(2 * v + 1, fine.height - 1)) * fine.width;
      float* dst = coarse.intensity.data() + static_cast<size_t>(v) * coarse.width;
      const int last = fine.width - 1;
      for (int u = 0; u < coarse.width; ++u) {
        const int u0 = std::min(2 * u, last), u1 = std::min(2 * u + 1, last);
        dst[u] = 0.25f * (a[u0] + a[u1] + b[u0] + b[u1]);
      }
    }
  }
}

void compute_gradients(IntensityLevel* level) {
  const int w = level->width, h = level->height;
  level->grad_u.assign(static_cast<size_t>(w) * h, 0.0f);
  level->grad_v.assign(static_cast<size_t>(w) * h, 0.0f);
  const float* I = level->intensity.data();
  for (int v = 1; v + 1 < h; ++v) {
    const size_t row = static_cast<size_t>(v) * w;
    float* gu = level->grad_u.data() + row;
    float* gv = level->grad_v.data() + row;
    const float* c = I + row;
    DF_IVDEP
    for (int u = 1; u + 1 < w; ++u) {
      gu[u] = 0.5f * (c[u + 1] - c[u - 1]);
      gv[u] = 0.5f * (c[u + w] - c[u - w]);
    }
  }
}

}  // namespace depthfuse
