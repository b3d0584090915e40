// The depth decoding pipeline, chosen by name (capture.kinect2_pipeline): "depthfuse" (raw packets
// from libfreenect2, decoded by depthfuse: packet_decoding.hpp) or one of libfreenect2's.
#pragma once

#include <memory>
#include <string>
#include <vector>

#include <libfreenect2/packet_pipeline.h>

#include "depthfuse/status.hpp"

namespace depthfuse::kinect2 {

// Every name capture.kinect2_pipeline accepts: depthfuse, cpu, opengl, opencl, cuda.
std::vector<std::string> known_pipelines();
// The ones usable here: depthfuse and cpu always, the others as compiled into libfreenect2.
std::vector<std::string> compiled_pipelines();

// Ok when `name` can be used here. kInvalidArgument for a name that is not a pipeline;
// kUnsupported, naming the libfreenect2 build option, for one not compiled into libfreenect2.
Status check_pipeline(const std::string& name);

// A new pipeline (check_pipeline first). libfreenect2's openDevice takes ownership of it.
Result<std::unique_ptr<libfreenect2::PacketPipeline>> make_packet_pipeline(const std::string& name);

}  // namespace depthfuse::kinect2
