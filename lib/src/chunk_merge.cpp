#include "chunk_merge.hpp"

#include <algorithm>
#include <cmath>
#include <limits>

#include "deformation_kernels.hpp"

namespace depthfuse {

namespace {

constexpr uint64_t kEmpty = ~uint64_t{0};
// The reach of a point that is no partner (merged away, or its information singular): no distance
// is within it.
constexpr float kNoReach = std::numeric_limits<float>::quiet_NaN();
constexpr int kCoordBits = 21;  // per axis in a packed cell key
constexpr uint32_t kCoordMax = (1u << kCoordBits) - 1;

inline uint64_t pack(uint32_t x, uint32_t y, uint32_t z) {
  return uint64_t{x} | (uint64_t{y} << kCoordBits) | (uint64_t{z} << (2 * kCoordBits));
}

inline uint32_t coord(uint64_t key, int axis) {
  return static_cast<uint32_t>(key >> (axis * kCoordBits)) & kCoordMax;
}

// Fibonacci hashing: the product's top bits, which every bit of the key reaches (its low bits
// would not depend on the key's high ones, and the cells of a wall would all collide).
inline size_t slot_hash(uint64_t key, int shift) {
  return static_cast<size_t>((key * 0x9E3779B97F4A7C15ull) >> shift);
}

}  // namespace

size_t ChunkMerger::find_slot(uint64_t key) const {
  const size_t mask = cells_.size() - 1;
  size_t s = slot_hash(key, shift_);
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
  // Where the points lie farther apart than their reach, cells twice their reach would hold one
  // point or none, and a point would look up 27 cells to find a few neighbours: cells are at
  // least twice the points' spacing on the surface (its area taken as the product of the bounding
  // box's two largest sides), about four points a cell. Coordinates must fit their bits: the
  // extent over h below 2^21.
  Eigen::Vector3f extent = hi - lo;
  std::sort(extent.data(), extent.data() + 3);
  const float spacing = std::sqrt(extent[1] * extent[2] / static_cast<float>(n));
  cell_m_ = std::max(
      {2.0f * quantile_[q], 2.0f * spacing, 1e-4f, extent[2] / static_cast<float>(kCoordMax - 2)});
  origin_m_ = lo;

  size_t capacity = 16;
  shift_ = 60;
  while (capacity < 2 * n) {
    capacity *= 2;
    --shift_;
  }
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
  rank_.resize(n);
  sorted_position_.resize(n);
  sorted_reach_.resize(n);
  for (size_t i = 0; i < n; ++i) {
    Cell& c = cells_[cell_of_[i]];
    const uint32_t o = c.begin + c.count++;
    order_[o] = static_cast<uint32_t>(i);
    rank_[i] = o;
    sorted_position_[o] = a.position_m[i];
    sorted_reach_[o] = std::isfinite(reach_[i]) ? reach_[i] : kNoReach;
  }
  return true;
}

int ChunkMerger::neighbours(uint64_t key, int k, Range* out) const {
  const int64_t cx = coord(key, 0), cy = coord(key, 1), cz = coord(key, 2);
  int n = 0;
  for (int64_t z = cz - k; z <= cz + k; ++z)
    for (int64_t y = cy - k; y <= cy + k; ++y)
      for (int64_t x = cx - k; x <= cx + k; ++x) {
        Range& r = out[n++];
        r = {0, 0};
        if (x < 0 || y < 0 || z < 0 || x > kCoordMax || y > kCoordMax || z > kCoordMax) continue;
        const Cell& c = cells_[find_slot(
            pack(static_cast<uint32_t>(x), static_cast<uint32_t>(y), static_cast<uint32_t>(z)))];
        if (c.key != kEmpty) r = {c.begin, c.begin + c.count};
      }
  return n;
}

int64_t ChunkMerger::partner(const PointArrays& a, size_t i, const std::vector<uint32_t>& segment,
                             PairGate* gate, const Range* ranges, int count) const {
  const float r_i = reach_[i];
  const Eigen::Vector3f p_i = a.position_m[i];
  const PointState& s_i = a.state[i];
  const Eigen::Vector3f n_i(s_i.nx, s_i.ny, s_i.nz);
  const Sym3f L_i = information_of(s_i);
  const uint32_t segment_i = segment[i];
  float best_d2 = std::numeric_limits<float>::infinity();
  int64_t best = -1;
  for (int r = 0; r < count; ++r) {
    for (uint32_t o = ranges[r].begin; o < ranges[r].end; ++o) {
      // Within the sum of the reaches first, in the cells' own contiguous copy: it rules out most
      // (and every point that is no partner: kNoReach).
      const Eigen::Vector3f d = sorted_position_[o] - p_i;
      const float reach = r_i + sorted_reach_[o];
      if (!(d.squaredNorm() <= reach * reach)) continue;
      const uint32_t j = order_[o];
      if (j == i || segment[j] == segment_i) continue;
      const PointState& s_j = a.state[j];
      if (n_i.dot(Eigen::Vector3f(s_j.nx, s_j.ny, s_j.nz)) <= 0.0f) continue;
      const float d2 = mahalanobis2(d, L_i);
      if (d2 < best_d2 && gate->moved_apart(segment_i, segment[j], p_i)) {
        best_d2 = d2;
        best = j;
      }
    }
  }
  return best;
}

size_t ChunkMerger::merge(PointArrays* a, size_t first, std::vector<uint32_t>* segment,
                          PairGate* gate) {
  const size_t n = a->size();
  if (first >= n || !build(*a)) return 0;
  keep_.assign(n, 1);
  size_t merged = 0;
  // Cell by cell: the neighbouring cells are looked up once for all the points of a cell. A point
  // reaching at most h/4 searches the 2 x 2 x 2 of them on its side of its cell (every point
  // within h/2 of it), one reaching at most h/2 all 27, one reaching farther the 125 within two.
  Range around[27], block[8], far[125];
  const float inv = 1.0f / cell_m_;
  for (const Cell& cell : cells_) {
    if (cell.key == kEmpty) continue;
    bool looked_up = false;
    const Eigen::Vector3f corner(static_cast<float>(coord(cell.key, 0)),
                                 static_cast<float>(coord(cell.key, 1)),
                                 static_cast<float>(coord(cell.key, 2)));
    for (uint32_t o = cell.begin; o < cell.begin + cell.count; ++o) {
      const size_t i = order_[o];
      if (i < first || !keep_[i] || !std::isfinite(reach_[i])) continue;
      if (!looked_up) neighbours(cell.key, 1, around);
      looked_up = true;
      int64_t j;
      if (reach_[i] <= 0.25f * cell_m_) {
        // The side of its cell the point lies on, per axis: the neighbour there (offset +-1).
        const Eigen::Vector3f f = (a->position_m[i] - origin_m_) * inv - corner;
        const int sx = f.x() < 0.5f ? -1 : 1, sy = f.y() < 0.5f ? -1 : 1,
                  sz = f.z() < 0.5f ? -1 : 1;
        int n = 0;
        for (int dz : {0, sz})
          for (int dy : {0, sy})
            for (int dx : {0, sx}) block[n++] = around[(dz + 1) * 9 + (dy + 1) * 3 + (dx + 1)];
        j = partner(*a, i, *segment, gate, block, n);
      } else if (reach_[i] <= 0.5f * cell_m_) {
        j = partner(*a, i, *segment, gate, around, 27);
      } else {
        j = partner(*a, i, *segment, gate, far, neighbours(cell.key, 2, far));
      }
      if (j < 0) continue;
      Eigen::Vector3f p;
      Sym3f L;
      if (!merge_rule(a->position_m[i], information_of(a->state[i]), a->position_m[j],
                      information_of(a->state[j]), &p, &L))
        continue;
      if (a->state[j].last_frame > a->state[i].last_frame) (*segment)[i] = (*segment)[j];
      absorb_point(*a, i, static_cast<size_t>(j), p, L);
      reach_[i] = reach_m(a->state[i]);
      sorted_position_[rank_[i]] = p;
      sorted_reach_[rank_[i]] = std::isfinite(reach_[i]) ? reach_[i] : kNoReach;
      sorted_reach_[rank_[j]] = kNoReach;
      keep_[j] = 0;
      ++merged;
    }
  }
  if (merged > 0) a->compact(keep_);
  return merged;
}

size_t ChunkMerger::memory_bytes() const {
  return cells_.capacity() * sizeof(Cell) + order_.capacity() * sizeof(uint32_t) +
         rank_.capacity() * sizeof(uint32_t) +
         sorted_position_.capacity() * sizeof(Eigen::Vector3f) +
         sorted_reach_.capacity() * sizeof(float) + cell_of_.capacity() * sizeof(uint32_t) +
         reach_.capacity() * sizeof(float) + quantile_.capacity() * sizeof(float) +
         keep_.capacity();
}

}  // namespace depthfuse
