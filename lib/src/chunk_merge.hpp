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
//  - a spatial hash of the chunk's points in cubic cells of edge h, twice the 90th percentile of
//    the points' reach (reach_m(): how far a point's ellipsoid reaches at most). Two points the
//    merge rule can accept lie within the sum of their reaches, so a point whose reach is at most
//    h/2 finds every partner in the 27 cells around its own; one that reaches farther searches the
//    125 around it (partners beyond that are left: a rare, very uncertain point);
//  - the occupied cells in an open-addressing table (`cells_`: a cell's packed coordinates, where
//    its points start in `order_` and how many there are), at most half full;
//  - `order_`: the point indices sorted by cell, by a counting sort (two passes over the points);
//  - per point: its cell's slot in the table, its reach, and whether it is kept.
class ChunkMerger {
 public:
  // Each point of `a` from index `first` on (earlier points only as partners) merges with its
  // partner, if the merge rule accepts the pair: among the points within reach that a different
  // keyframe segment fused (`segment`, one per point; a point fused again takes the newer
  // point's) and whose normal faces the same way, the nearest in the point's own metric (its
  // information). The partner is removed: `a` is compacted (and `segment` is not). Returns how many
  // points were removed.
  //
  // Why only across segments: a segment's points moved rigidly together, so no two of them lie
  // closer than fusion left them; and two neighbours of one surface a pixel apart pass the merge
  // rule while they are young (the lateral sigma is a pixel's footprint), so merging them would
  // thin the cloud instead of removing a second layer. Why the normals: the two sides of a thin
  // object are two surfaces, which fusion never pairs (a camera sees one side).
  size_t merge(PointArrays* a, size_t first, std::vector<uint32_t>* segment);

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
  // The partner of point i (see merge()), -1 if none.
  int64_t partner(const PointArrays& a, size_t i, const std::vector<uint32_t>& segment) const;

  float cell_m_ = 0;             // h
  Eigen::Vector3f origin_m_;     // the cells' corner: the points' bounding box's lowest
  std::vector<Cell> cells_;      // size a power of two
  std::vector<uint32_t> order_;
  std::vector<uint32_t> cell_of_;  // per point: its cell's slot in cells_
  std::vector<float> reach_;       // per point, m
  std::vector<float> quantile_;    // scratch for the percentile
  std::vector<uint8_t> keep_;      // per point: 0 once merged into another
};

}  // namespace depthfuse
