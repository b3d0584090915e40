#include "chunk_merge.hpp"

#include <algorithm>
#include <cmath>
#include <limits>

#include "deformation_kernels.hpp"

namespace depthfuse {

namespace {

constexpr uint64_t kEmpty = ~uint64_t{0};
constexpr int kCoordBits = 21;  // per axis in a packed cell key
constexpr uint32_t kCoordMax = (1u << kCoordBits) - 1;

inline uint64_t pack(uint32_t x, uint32_t y, uint32_t z) {
  return uint64_t{x} | (uint64_t{y} << kCoordBits) | (uint64_t{z} << (2 * kCoordBits));
}

inline uint32_t coord(uint64_t key, int axis) {
  return static_cast<uint32_t>(key >> (axis * kCoordBits)) & kCoordMax;
}

inline size_t slot_hash(uint64_t key, size_t mask) {
  // Fibonacci hashing: neighbouring cells land far apart.
  return static_cast<size_t>((key * 0x9E3779B97F4A7C15ull) >> 20) & mask;
}

}  // namespace

size_t ChunkMerger::find_slot(uint64_t key) const {
  const size_t mask = cells_.size() - 1;
  size_t s = slot_hash(key, mask);
  while (cells_[s].key != kEmpty && cells_[s].key != key) s = (s + 1) & mask;
  return s;
}

bool ChunkMerger::build(const PointArrays& a) {
  const size_t n = a.size();
  reach_.resize(n);
  quantile_.clear();
  Eigen::Vector3f lo = Eigen::Vector3f::Constant(std::numeric_limits<float>::infinity());
  Eigen::Vector3f hi = -lo;
  for (size_t i = 0; i < n; ++i) {
    reach_[i] = reach_m(a.state[i]);
    if (std::isfinite(reach_[i])) quantile_.push_back(reach_[i]);
    lo = lo.cwiseMin(a.position_m[i]);
    hi = hi.cwiseMax(a.position_m[i]);
  }
  if (quantile_.empty() || !lo.allFinite() || !hi.allFinite()) return false;
  const size_t q = quantile_.size() * 9 / 10;
  std::nth_element(quantile_.begin(), quantile_.begin() + q, quantile_.end());
  // Coordinates must fit their bits: a chunk's extent over h below 2^21.
  const float extent = (hi - lo).maxCoeff();
  cell_m_ = std::max({2.0f * quantile_[q], 1e-4f, extent / static_cast<float>(kCoordMax - 2)});
  origin_m_ = lo;

  size_t capacity = 16;
  while (capacity < 2 * n) capacity *= 2;
  cells_.assign(capacity, Cell{kEmpty, 0, 0});
  cell_of_.resize(n);
  const float inv = 1.0f / cell_m_;
  for (size_t i = 0; i < n; ++i) {
    const Eigen::Vector3f c = (a.position_m[i] - origin_m_) * inv;
    const uint64_t key = pack(static_cast<uint32_t>(c.x()), static_cast<uint32_t>(c.y()),
                              static_cast<uint32_t>(c.z()));
    const size_t s = find_slot(key);
    cells_[s].key = key;
    ++cells_[s].count;
    cell_of_[i] = static_cast<uint32_t>(s);
  }
  uint32_t begin = 0;
  for (Cell& c : cells_) {
    c.begin = begin;
    begin += c.count;
    c.count = 0;  // refilled below
  }
  order_.resize(n);
  for (size_t i = 0; i < n; ++i) {
    Cell& c = cells_[cell_of_[i]];
    order_[c.begin + c.count++] = static_cast<uint32_t>(i);
  }
  return true;
}

int64_t ChunkMerger::partner(const PointArrays& a, size_t i,
                             const std::vector<uint32_t>& segment) const {
  const float r_i = reach_[i];
  const Eigen::Vector3f p_i = a.position_m[i];
  const PointState& s_i = a.state[i];
  const Eigen::Vector3f n_i(s_i.nx, s_i.ny, s_i.nz);
  const Sym3f L_i = information_of(s_i);
  const int k = r_i <= 0.5f * cell_m_ ? 1 : 2;
  const uint64_t key = cells_[cell_of_[i]].key;
  const int64_t cx = coord(key, 0), cy = coord(key, 1), cz = coord(key, 2);
  float best_d2 = std::numeric_limits<float>::infinity();
  int64_t best = -1;
  for (int64_t z = cz - k; z <= cz + k; ++z) {
    for (int64_t y = cy - k; y <= cy + k; ++y) {
      for (int64_t x = cx - k; x <= cx + k; ++x) {
        if (x < 0 || y < 0 || z < 0 || x > kCoordMax || y > kCoordMax || z > kCoordMax) continue;
        const Cell& c =
            cells_[find_slot(pack(static_cast<uint32_t>(x), static_cast<uint32_t>(y),
                                  static_cast<uint32_t>(z)))];
        if (c.key == kEmpty) continue;
        for (uint32_t o = c.begin; o < c.begin + c.count; ++o) {
          const uint32_t j = order_[o];
          if (j == i || !keep_[j] || segment[j] == segment[i]) continue;
          const Eigen::Vector3f d = a.position_m[j] - p_i;
          const float r = r_i + reach_[j];  // infinite reach: never within (see build())
          if (!(d.squaredNorm() <= r * r) || !std::isfinite(reach_[j])) continue;
          const PointState& s_j = a.state[j];
          if (n_i.dot(Eigen::Vector3f(s_j.nx, s_j.ny, s_j.nz)) <= 0.0f) continue;
          const float d2 = mahalanobis2(d, L_i);
          if (d2 < best_d2) {
            best_d2 = d2;
            best = j;
          }
        }
      }
    }
  }
  return best;
}

size_t ChunkMerger::merge(PointArrays* a, size_t first, std::vector<uint32_t>* segment) {
  const size_t n = a->size();
  if (first >= n || !build(*a)) return 0;
  keep_.assign(n, 1);
  size_t merged = 0;
  for (size_t i = first; i < n; ++i) {
    if (!keep_[i] || !std::isfinite(reach_[i])) continue;
    const int64_t j = partner(*a, i, *segment);
    if (j < 0) continue;
    Eigen::Vector3f p;
    Sym3f L;
    if (!merge_rule(a->position_m[i], information_of(a->state[i]), a->position_m[j],
                    information_of(a->state[j]), &p, &L))
      continue;
    if (a->state[j].last_frame > a->state[i].last_frame) (*segment)[i] = (*segment)[j];
    absorb_point(*a, i, static_cast<size_t>(j), p, L);
    reach_[i] = reach_m(a->state[i]);
    keep_[j] = 0;
    ++merged;
  }
  if (merged > 0) a->compact(keep_);
  return merged;
}

size_t ChunkMerger::memory_bytes() const {
  return cells_.capacity() * sizeof(Cell) + order_.capacity() * sizeof(uint32_t) +
         cell_of_.capacity() * sizeof(uint32_t) + reach_.capacity() * sizeof(float) +
         quantile_.capacity() * sizeof(float) + keep_.capacity();
}

}  // namespace depthfuse
