// The capture daemon's command line (see capture_options.hpp), read once by main().
#include "capture_options.hpp"

namespace depthfuse::capture {

const std::vector<std::string> kCaptureOptionNames = {"source", "rate", "name", "color",
                                                      "depth-encoding", "depth-unit"};
const std::vector<std::string> kCaptureFlagNames = {"loop", "linger"};

Result<CaptureOptions> capture_options(const daemon::Args& args, const AppConfig& config) {
  CaptureOptions o;
  o.name = args.get("name", o.name);
  o.source_spec = args.get("source", config.capture.source);
  o.loop = args.has("loop") || config.capture.loop;
  o.linger = args.has("linger");

  const std::string depth_encoding = args.get("depth-encoding", "zstd");
  if (depth_encoding == "raw") {
    o.depth.compress = false;
  } else if (depth_encoding != "zstd") {
    return invalid_argument("--depth-encoding must be zstd or raw");
  }
  std::string error;
  if (!args.get_double("depth-unit", &o.depth.depth_unit_m, &error, daemon::open_closed(0, 1)))
    return invalid_argument(error + " (metres per count)");

  const std::string color = args.get("color", "zstd");
  if (color == "raw") o.color.encoding = lcm::ColorEncoding::kRaw;
  else if (color == "jpeg") o.color.encoding = lcm::ColorEncoding::kJpeg;
  else if (color == "none") o.send_color = false;
  else if (color != "zstd") return invalid_argument("--color must be zstd, raw, jpeg or none");

  auto rate = parse_rate(args.get("rate"));
  if (!rate.is_ok()) return rate.status();
  o.rate = rate.value();
  return o;
}

}  // namespace depthfuse::capture
