// Counter-based random numbers: every draw is a hash of (seed, frame, pixel, stream), so results do
// not depend on the order or the thread in which pixels and frames are produced, and identical
// seeds give identical data on every platform (no std:: distributions, whose output is
// implementation-defined).
#pragma once

#include <cmath>
#include <cstdint>

namespace depthfuse::synthetic::detail {

// The splitmix64 output function: a bijective 64-bit mixer with good avalanche.
inline uint64_t mix64(uint64_t x) {
  x += 0x9e3779b97f4a7c15ull;
  x = (x ^ (x >> 30)) * 0xbf58476d1ce4e5b9ull;
  x = (x ^ (x >> 27)) * 0x94d049bb133111ebull;
  return x ^ (x >> 31);
}

inline uint64_t hash_combine(uint64_t a, uint64_t b) { return mix64(a ^ mix64(b)); }

// Independent streams of one seed.
enum Stream : uint64_t {
  kStreamPixelNoise = 0x6e6f697365ull,      // per-frame sensor noise
  kStreamPosePerturbation = 0x706f7365ull,  // per-frame pose perturbation
  kStreamSceneLayout = 0x7363656e65ull,     // box layout of the built-in scenes
};

inline uint64_t stream_key(uint64_t seed, Stream stream, uint64_t index) {
  return hash_combine(hash_combine(seed, stream), index);
}

// Uniform in [0, 1) from the top 53 bits.
inline double uniform01(uint64_t bits) { return static_cast<double>(bits >> 11) * 0x1.0p-53; }

// Uniform in [0, 1) from 21 bits of `bits` starting at `shift` (three draws per 64-bit hash).
inline double uniform21(uint64_t bits, int shift) {
  return static_cast<double>((bits >> shift) & 0x1fffffull) * (1.0 / 2097152.0);
}

// An approximately standard normal draw from one hash: the Irwin-Hall sum of six 10-bit uniforms,
// centred and scaled to unit variance (tails end at +-4.2 sigma, excess kurtosis -0.2). Cheap
// enough for every pixel of every frame, unlike Box-Muller.
inline double fast_gaussian(uint64_t bits) {
  const uint64_t s = (bits & 1023u) + ((bits >> 10) & 1023u) + ((bits >> 20) & 1023u) +
                     ((bits >> 30) & 1023u) + ((bits >> 40) & 1023u) + ((bits >> 50) & 1023u);
  // mean 6 * 1023 / 2, variance 6 * (1024^2 - 1) / 12
  constexpr double kMean = 3069.0;
  constexpr double kInvStd = 1.0 / 724.0769986679594;  // sqrt((1024^2 - 1) / 2)
  return (static_cast<double>(s) - kMean) * kInvStd;
}

// An exact standard normal pair (Box-Muller) from two hashes, for the few draws per frame.
inline void gaussian_pair(uint64_t h1, uint64_t h2, double* g1, double* g2) {
  const double u1 = 1.0 - uniform01(h1);  // (0, 1]
  const double u2 = uniform01(h2);
  const double r = std::sqrt(-2.0 * std::log(u1));
  const double a = 6.283185307179586476925 * u2;
  *g1 = r * std::cos(a);
  *g2 = r * std::sin(a);
}

// A small sequential generator over the hash, for scene layout.
class HashRng {
 public:
  explicit HashRng(uint64_t key) : state_(key) {}
  uint64_t next_u64() { return mix64(state_++ ^ 0xa0761d6478bd642full); }
  double uniform() { return uniform01(next_u64()); }
  double uniform(double lo, double hi) { return lo + (hi - lo) * uniform(); }
  int uniform_int(int lo, int hi_inclusive) {
    return lo + static_cast<int>(uniform() * (hi_inclusive - lo + 1));
  }
  double gaussian() {
    double g1, g2;
    gaussian_pair(next_u64(), next_u64(), &g1, &g2);
    return g1;
  }

 private:
  uint64_t state_;
};

}  // namespace depthfuse::synthetic::detail
