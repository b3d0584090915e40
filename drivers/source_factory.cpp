#include "depthfuse/source_factory.hpp"

#if DEPTHFUSE_HAVE_REPLAY
#include "depthfuse/replay/tum_source.hpp"
#endif
#if DEPTHFUSE_HAVE_SYNTHETIC
#include "depthfuse/synthetic/synthetic_source.hpp"
#endif
#if DEPTHFUSE_HAVE_KINECT2
#include "depthfuse/kinect2/kinect2_source.hpp"
#endif
#if DEPTHFUSE_HAVE_KINECT2_SIM
#include "depthfuse/kinect2/kinect2_sim_source.hpp"
#endif
#if DEPTHFUSE_HAVE_LCMLOG
#include "depthfuse/lcmlog/lcmlog_source.hpp"
#endif

namespace depthfuse {
namespace {

// "kind:argument" → {kind, argument}.
std::pair<std::string, std::string> split_spec(const std::string& spec) {
  const auto colon = spec.find(':');
  return {spec.substr(0, colon), colon == std::string::npos ? std::string() : spec.substr(colon + 1)};
}

}  // namespace

// Each driver exports open_<driver>_source(argument, config) from its public header; this file
// only splits the spec and dispatches.
Result<std::unique_ptr<FrameSource>> open_frame_source(const std::string& spec,
                                                       const AppConfig& config) {
  const auto [kind, arg] = split_spec(spec);
  (void)config;
  (void)arg;

  if (kind == "tum") {
#if DEPTHFUSE_HAVE_REPLAY
    return replay::open_tum_source(arg, config);
#else
    return unsupported("the replay driver is not built in");
#endif
  }
  if (kind == "synthetic") {
#if DEPTHFUSE_HAVE_SYNTHETIC
    return open_synthetic_source(arg, config);
#else
    return unsupported("the synthetic driver is not built in");
#endif
  }
  if (kind == "kinect2") {
#if DEPTHFUSE_HAVE_KINECT2
    return kinect2::open_kinect2_source(arg, config);
#else
    return unsupported(
        "the kinect2 source is not built in: libfreenect2 was not found when depthfuse was built. "
        "Install libfreenect2 (see docs/kinect2.md: build it from source with cmake and "
        "'make install'), then re-run tools/setup.sh or cmake so that the driver is compiled");
#endif
  }
  if (kind == "kinect2sim") {
#if DEPTHFUSE_HAVE_KINECT2_SIM
    return kinect2::open_kinect2sim_source(arg, config);
#else
    return unsupported(
        "the kinect2sim source is not built in: it runs the kinect2 driver's path, which needs "
        "libfreenect2 (see docs/kinect2.md)");
#endif
  }
  if (kind == "lcmlog") {
#if DEPTHFUSE_HAVE_LCMLOG
    return lcmlog::open_lcmlog_source(arg, config);
#else
    return unsupported("the lcmlog driver is not built in");
#endif
  }
  return invalid_argument("unknown frame source '" + spec +
                          "': expected tum:<folder>, synthetic:<corner|room|rooms>, "
                          "kinect2[:serial], kinect2sim:<corner|room|rooms> or lcmlog:<file>");
}

std::optional<DeviceStatus> device_status_before_open(const std::string& spec,
                                                      const AppConfig& config,
                                                      const std::string& detail) {
  const auto [kind, arg] = split_spec(spec);
#if DEPTHFUSE_HAVE_KINECT2
  if (kind == "kinect2") return kinect2::kinect2_status_before_open(arg, config, detail);
#endif
  (void)kind;
  (void)arg;
  (void)config;
  (void)detail;
  return std::nullopt;
}

}  // namespace depthfuse
