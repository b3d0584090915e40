// Internal: the merge pass of the map's deformation over one chunk. After a loop closure has moved
// the chunk's points with their keyframes, the surfaces two visits left apart lie on each other;
// this fuses them into one with the paper's merge rule (MapDeformation::update()).
#pragma once

#include <cstddef>
#include <cstdint>
#include <vector>

#include "depthfuse/point_arrays.hpp"

namespace depthfuse {

// The pass is linear in the chunk's points and allocates nothing per point: its buffers are kept
// from chunk to chunk, grown to the largest. Their layout:
//  - a spatial hash of the chunk's points in cubic cells of edge h: twice the 90th percentile of
//    the points' reach (reach_m(): how far a point's ellipsoid reaches at most), or twice their
//    spacing on the surface if that is more (a few points a cell). Two points the merge rule can
//    accept lie within the sum of their reaches: a point reaching at most h/4 finds every partner
//    reaching as little in the 2 x 2 x 2 cells on its side of its own cell (all within h/2); one
//    reaching at most h/2 searches the 27 cells around its own, one reaching farther the 125
//    within two (partners beyond are left: a rare, very uncertain point). Where points lie
//    farther apart than they reach (most of a fused map) the 8 cells hold half the candidates the
//    27 would;
//  - the occupied cells in an open-addressing table (`cells_`: a cell's packed coordinates, where
//    its points start in `order_` and how many there are), at most half full;
//  - `order_`: the point indices sorted by cell, by a counting sort (two passes over the points),
//    and beside it the points' positions and reaches in the same order, read contiguously;
//  - per point: its cell's slot in the table, its place in order_, its reach, whether it is kept.
// The pass goes cell by cell, so that a cell's neighbours are looked up once for all its points.
// Whether the correction being applied moved the points of keyframe segments a and b apart at p
// (by more than a fraction of their uncertainty). Where it did not, two of their points lie as they
// did when fusion saw them, and what fusion left apart stays apart.
class PairGate {
 public:
  virtual bool moved_apart(uint32_t a, uint32_t b, const Eigen::Vector3f& p) = 0;

 protected:
  ~PairGate() = default;
};

class ChunkMerger {
 public:
  // Each point of `a` from index `first` on (earlier points only as partners), cell by cell,
  // merges with its partner if the merge rule accepts the pair: among the points within reach
  // that a different keyframe segment fused (`segment`, one per point; a point fused again takes
  // the newer point's), which the correction moved apart from it (`gate`), and whose normal faces
  // the same way, the nearest in the point's own metric (its information). The partner is
  // removed: `a` is compacted (and `segment` is not). Returns how many points were removed.
  //
  // Why only points the correction moved relative to each other (other segments, moved apart):
  // only they can lie on each other now and not before; and the merge rule accepts two young
  // neighbours of one surface a pixel apart (the lateral sigma is a pixel's footprint), which
  // fusion never compares (it pairs a measurement with a point, never two points), so merging
  // those would thin the cloud instead of removing a second layer. Why the normals: the two sides
  // of a thin object are two surfaces, which fusion never pairs (a camera sees one side).
  size_t merge(PointArrays* a, size_t first, std::vector<uint32_t>* segment, PairGate* gate);

  size_t memory_bytes() const;

 private:
  struct Cell {
    uint64_t key;    // packed cell coordinates; kEmpty where the slot is free
    uint32_t begin;  // its points are order_[begin, begin + count)
    uint32_t count;
  };
  // Builds the spatial hash of a's points; false when no point has a finite reach.
  bool build(const PointArrays& a);
  // The table slot of a cell, or of the free slot where it would go.
  size_t find_slot(uint64_t key) const;
  // Points order_[begin, end).
  struct Range {
    uint32_t begin, end;
  };
  // The cells within k cells of a cell (k = 1: 27, 2: 125), x fastest, into out (an empty range
  // for a cell without points); their count.
  int neighbours(uint64_t key, int k, Range* out) const;
  // The partner of point i (see merge()) among the points of `ranges`, -1 if none.
  int64_t partner(const PointArrays& a, size_t i, const std::vector<uint32_t>& segment,
                  PairGate* gate, const Range* ranges, int count) const;

  float cell_m_ = 0;          // h
  Eigen::Vector3f origin_m_;  // the cells' corner: the points' bounding box's lowest
  std::vector<Cell> cells_;   // size a power of two, 2^(64 - shift_)
  int shift_ = 60;
  std::vector<uint32_t> order_;
  std::vector<uint32_t> rank_;  // per point: its index in order_
  // Per index in order_: the point's position and reach (kNoReach where it is no partner), so
  // that a cell's points are read contiguously.
  std::vector<Eigen::Vector3f> sorted_position_;
  std::vector<float> sorted_reach_;
  std::vector<uint32_t> cell_of_;  // per point: its cell's slot in cells_
  std::vector<float> reach_;       // per point, m
  std::vector<float> quantile_;    // scratch for the percentile
  std::vector<uint8_t> keep_;      // per point: 0 once merged into another
};

}  // namespace depthfuse
