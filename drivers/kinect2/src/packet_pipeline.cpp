#include "depthfuse/kinect2/packet_pipeline.hpp"

#include <libfreenect2/config.h>

namespace depthfuse::kinect2 {

namespace {

std::string joined(const std::vector<std::string>& names) {
  std::string text;
  for (const auto& name : names) text += (text.empty() ? "" : ", ") + name;
  return text;
}

}  // namespace

std::vector<std::string> known_pipelines() {
  return {"depthfuse", "cpu", "opengl", "opencl", "cuda"};
}

std::vector<std::string> compiled_pipelines() {
  std::vector<std::string> names{"depthfuse", "cpu"};
#ifdef LIBFREENECT2_WITH_OPENGL_SUPPORT
  names.push_back("opengl");
#endif
#ifdef LIBFREENECT2_WITH_OPENCL_SUPPORT
  names.push_back("opencl");
#endif
#ifdef LIBFREENECT2_WITH_CUDA_SUPPORT
  names.push_back("cuda");
#endif
  return names;
}

Status check_pipeline(const std::string& name) {
  for (const auto& compiled : compiled_pipelines())
    if (compiled == name) return Status::ok();
  std::string option;
  if (name == "opengl") option = "ENABLE_OPENGL (needs libglfw3-dev and OpenGL 3.1)";
  if (name == "opencl") option = "ENABLE_OPENCL (needs an OpenCL 1.1 ICD and headers)";
  if (name == "cuda") option = "ENABLE_CUDA (needs the CUDA toolkit)";
  if (option.empty())
    return invalid_argument("capture.kinect2_pipeline: unknown depth pipeline '" + name +
                            "': expected one of " + joined(known_pipelines()));
  return unsupported("capture.kinect2_pipeline = \"" + name + "\": the " + name +
                     " depth pipeline is not compiled into libfreenect2 " LIBFREENECT2_VERSION
                     " (built with: " +
                     joined(compiled_pipelines()) + "). Use one of those, or rebuild libfreenect2 with " +
                     option + "; see docs/kinect2.md");
}

Result<std::unique_ptr<libfreenect2::PacketPipeline>> make_packet_pipeline(const std::string& name) {
  DF_RETURN_IF_ERROR(check_pipeline(name));
  // libfreenect2 hands over the raw packets and the P0 tables; depthfuse decodes them.
  if (name == "depthfuse")
    return std::unique_ptr<libfreenect2::PacketPipeline>(new libfreenect2::DumpPacketPipeline());
  if (name == "cpu") return std::unique_ptr<libfreenect2::PacketPipeline>(new libfreenect2::CpuPacketPipeline());
#ifdef LIBFREENECT2_WITH_OPENGL_SUPPORT
  if (name == "opengl")
    return std::unique_ptr<libfreenect2::PacketPipeline>(new libfreenect2::OpenGLPacketPipeline());
#endif
#ifdef LIBFREENECT2_WITH_OPENCL_SUPPORT
  if (name == "opencl")
    return std::unique_ptr<libfreenect2::PacketPipeline>(new libfreenect2::OpenCLPacketPipeline());
#endif
#ifdef LIBFREENECT2_WITH_CUDA_SUPPORT
  if (name == "cuda")
    return std::unique_ptr<libfreenect2::PacketPipeline>(new libfreenect2::CudaPacketPipeline());
#endif
  return internal_error("depth pipeline '" + name + "' passed the check but has no constructor");
}

}  // namespace depthfuse::kinect2
