// The paper's method end to end, in the shapes depthfuse needs:
//  - IncrementalReconstructor (incremental.hpp): one frame at a time into a growing map;
//  - FramePath (frame_path.hpp): one frame's whole path through a scan (predict, prepare the map,
//    process, record), the same for the fusion daemon and the offline tools;
//  - reconstruct_batch and track_sequence (batch.hpp): a whole sequence.
#pragma once

#include "depthfuse/batch.hpp"
#include "depthfuse/frame_path.hpp"
#include "depthfuse/incremental.hpp"
