// Internal: the column layout of fusion's per-pixel data, described once. Fusion keeps what it
// works on a row at a time as structure-of-arrays, one float array per quantity, so that its row
// loops read and write contiguous memory and vectorise: the merge candidate rendered at each pixel
// (ModelProjection) and one image row's measurements with their merges (RowScratch). The views
// below are pointers to the first pixel of a stretch (F: float to write, const float to read);
// each is laid over consecutive arrays of its owner by over(), so the order of the columns is
// written down here alone.
#pragma once

#include <algorithm>
#include <cstddef>
#include <cstdint>
#include <vector>

#include "geometry.hpp"

namespace depthfuse {

// A 3-vector per pixel: x, y, z.
template <typename F>
struct Vec3Columns {
  static constexpr int kColumns = 3;
  F *x, *y, *z;

  DF_INLINE Eigen::Vector3f operator[](size_t i) const { return {x[i], y[i], z[i]}; }
  DF_INLINE void set(size_t i, const Eigen::Vector3f& v) const {
    x[i] = v.x(); y[i] = v.y(); z[i] = v.z();
  }
  Vec3Columns from(size_t first) const { return {x + first, y + first, z + first}; }
  operator Vec3Columns<const F>() const { return {x, y, z}; }
  template <typename Vector>
  static Vec3Columns over(Vector* column, size_t first) {
    return {column[0].data() + first, column[1].data() + first, column[2].data() + first};
  }
};

// A symmetric 3x3 matrix per pixel (Sym3f): xx, xy, xz, yy, yz, zz.
template <typename F>
struct Sym3Columns {
  static constexpr int kColumns = 6;
  F *xx, *xy, *xz, *yy, *yz, *zz;

  DF_INLINE Sym3f operator[](size_t i) const { return {xx[i], xy[i], xz[i], yy[i], yz[i], zz[i]}; }
  DF_INLINE void set(size_t i, const Sym3f& a) const {
    xx[i] = a.xx; xy[i] = a.xy; xz[i] = a.xz; yy[i] = a.yy; yz[i] = a.yz; zz[i] = a.zz;
  }
  Sym3Columns from(size_t first) const {
    return {xx + first, xy + first, xz + first, yy + first, yz + first, zz + first};
  }
  operator Sym3Columns<const F>() const { return {xx, xy, xz, yy, yz, zz}; }
  template <typename Vector>
  static Sym3Columns over(Vector* column, size_t first) {
    return {column[0].data() + first, column[1].data() + first, column[2].data() + first,
            column[3].data() + first, column[4].data() + first, column[5].data() + first};
  }
};

// A point as fusion sees it, per pixel: world position (m), information (1/m^2), unit normal
// (world frame).
template <typename F>
struct PointColumns {
  static constexpr int kColumns = 2 * Vec3Columns<F>::kColumns + Sym3Columns<F>::kColumns;
  Vec3Columns<F> position;
  Sym3Columns<F> information;
  Vec3Columns<F> normal;

  DF_INLINE void set(size_t i, const Eigen::Vector3f& p, const Sym3f& L,
                     const Eigen::Vector3f& n) const {
    position.set(i, p);
    information.set(i, L);
    normal.set(i, n);
  }
  PointColumns from(size_t first) const {
    return {position.from(first), information.from(first), normal.from(first)};
  }
  operator PointColumns<const F>() const { return {position, information, normal}; }
  template <typename Vector>
  static PointColumns over(Vector* column, size_t first) {
    constexpr int kPosition = 0, kInformation = kPosition + Vec3Columns<F>::kColumns,
                  kNormal = kInformation + Sym3Columns<F>::kColumns;
    return {Vec3Columns<F>::over(column + kPosition, first),
            Sym3Columns<F>::over(column + kInformation, first),
            Vec3Columns<F>::over(column + kNormal, first)};
  }
};

// The merge candidate rendered at each pixel (ModelProjection::gather_candidates()): its point as
// it stands now, its merge count, and its chunk's slot, >= 0 where the pixel has a candidate.
// Where a pixel has none the point's columns hold stale but finite values.
struct CandidateColumns {
  PointColumns<const float> point;
  const uint16_t* merges;
  const int32_t* slot;

  CandidateColumns from(size_t first) const {
    return {point.from(first), merges + first, slot + first};
  }
};

// One image row's measurements, worked out for the whole row at once (fusion's prepare_row()):
// each with its merge with the candidate rendered at its own pixel, as the candidates stood before
// the row was fused; and with a 3x3 window, the window's other candidate it would merge with next
// (select_window_3x3()).
struct RowColumns {
  static constexpr int kFloatColumns =
      PointColumns<float>::kColumns + 1 + 2 * Vec3Columns<float>::kColumns;
  PointColumns<float> measurement;  // the measurement in the world frame
  float* range_m;                   // its distance from the camera
  // The point merged with the pixel's own candidate (the merged information is the sum of the
  // two, not stored) and its normal, the running mean (running_mean_normal()) ...
  Vec3Columns<float> merged_position, merged_normal;
  uint8_t* merges;                  // ... if the merge rule accepts the merge
  // The window's candidate nearest in the measurement's metric, its own pixel's excluded, as the
  // candidates stood before the row was fused: its pixel, -1 if none.
  int32_t* window_px;
};

// The arrays behind a RowColumns, one per thread, kept from frame to frame. Each column is an
// array of its own: columns of one block a power of two apart would share cache sets.
class RowScratch {
 public:
  void resize(int width) {
    const size_t n = static_cast<size_t>(std::max(0, width));
    for (std::vector<float>& column : columns_) column.resize(n);
    merges_.resize(n);
    window_px_.resize(n);
  }
  RowColumns columns() {
    std::vector<float>* c = columns_;
    constexpr int kRange = PointColumns<float>::kColumns, kMergedPosition = kRange + 1,
                  kMergedNormal = kMergedPosition + Vec3Columns<float>::kColumns;
    return {PointColumns<float>::over(c, 0),
            c[kRange].data(),
            Vec3Columns<float>::over(c + kMergedPosition, 0),
            Vec3Columns<float>::over(c + kMergedNormal, 0),
            merges_.data(),
            window_px_.data()};
  }

 private:
  std::vector<float> columns_[RowColumns::kFloatColumns];
  std::vector<uint8_t> merges_;
  std::vector<int32_t> window_px_;
};

}  // namespace depthfuse
