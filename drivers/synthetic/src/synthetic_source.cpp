#include "depthfuse/synthetic/synthetic_source.hpp"

#include <charconv>
#include <cstdio>
#include <string>
#include <string_view>
#include <utility>

namespace depthfuse {
namespace synthetic {

SyntheticSource::SyntheticSource(SyntheticSequence sequence, bool with_noise)
    : sequence_(std::move(sequence)), with_noise_(with_noise), next_index_(first_frame()) {}

Result<Frame> SyntheticSource::next() {
  if (next_index_ >= sequence_.size()) return end_of_stream();
  Frame frame;
  sequence_.render_into(next_index_, with_noise_, &frame, true);
  ++next_index_;
  return frame;
}

std::string SyntheticSource::describe() const {
  const SyntheticConfig& c = sequence_.config();
  std::string s = std::string("synthetic:") + to_string(c.scene) + " (" +
                  std::to_string(sequence_.size()) + " frames, seed " + std::to_string(c.seed);
  if (c.pose_noise_m > 0.0 || c.pose_noise_deg > 0.0) {
    char buf[96];
    std::snprintf(buf, sizeof(buf), ", pose noise %g m / %g deg", c.pose_noise_m, c.pose_noise_deg);
    s += buf;
  }
  if (!with_noise_ || !c.noise.enabled) s += ", no sensor noise";
  if (!c.pose_hints) s += ", no pose hints";
  if (c.first_frame > 0) s += ", from frame " + std::to_string(c.first_frame);
  return s + ")";
}

Status SyntheticSource::rewind() {
  next_index_ = first_frame();
  return Status::ok();
}

namespace {

template <typename T>
bool parse_number(std::string_view text, T* out) {
  if (text.empty()) return false;
  const char* end = text.data() + text.size();
  auto [ptr, ec] = std::from_chars(text.data(), end, *out);
  return ec == std::errc() && ptr == end;
}

}  // namespace

Result<SyntheticConfig> parse_synthetic_spec(const std::string& arg, const SyntheticConfig& base) {
  const std::string context = "synthetic source '" + arg + "'";
  const size_t q = arg.find('?');
  const std::string kind_text = arg.substr(0, q);
  Result<SceneKind> kind = parse_scene_kind(kind_text);
  if (!kind.is_ok()) return kind.status().with_context(context);
  SyntheticConfig config = base;
  config.scene = kind.value();
  // A lap walk is made for its own length; the others keep the caller's.
  if (config.scene == SceneKind::kFurnished || config.scene == SceneKind::kPlain)
    config.frames = default_frames(config.scene);

  if (q != std::string::npos) {
    std::string_view query(arg);
    query.remove_prefix(q + 1);
    while (!query.empty()) {
      const size_t amp = query.find('&');
      const std::string_view item = query.substr(0, amp);
      query = amp == std::string_view::npos ? std::string_view() : query.substr(amp + 1);
      if (item.empty()) continue;
      const size_t eq = item.find('=');
      const std::string key(item.substr(0, eq));
      const std::string value(eq == std::string_view::npos ? std::string_view()
                                                           : item.substr(eq + 1));
      auto bad = [&](const char* expected) {
        return invalid_argument(context + ": bad value '" + value + "' for '" + key +
                                "' (expected " + expected + ")");
      };
      if (eq == std::string_view::npos)
        return invalid_argument(context + ": '" + key + "' has no value (expected key=value)");
      if (key == "frames") {
        if (!parse_number(value, &config.frames) || config.frames < 1)
          return bad("an integer >= 1");
      } else if (key == "first") {
        if (!parse_number(value, &config.first_frame) || config.first_frame < 0)
          return bad("a non-negative integer");
      } else if (key == "seed") {
        if (!parse_number(value, &config.seed)) return bad("a non-negative integer");
      } else if (key == "pose_noise_m") {
        if (!parse_number(value, &config.pose_noise_m) || !(config.pose_noise_m >= 0.0))
          return bad("a number >= 0");
      } else if (key == "pose_noise_deg") {
        if (!parse_number(value, &config.pose_noise_deg) || !(config.pose_noise_deg >= 0.0))
          return bad("a number >= 0");
      } else if (key == "rate_hz") {
        if (!parse_number(value, &config.rate_hz) || !(config.rate_hz > 0.0))
          return bad("a number > 0");
      } else if (key == "noise" || key == "hints") {
        bool on = false;
        if (value == "1" || value == "true" || value == "on") {
          on = true;
        } else if (!(value == "0" || value == "false" || value == "off")) {
          return bad("0 or 1");
        }
        (key == "noise" ? config.noise.enabled : config.pose_hints) = on;
      } else {
        return invalid_argument(context + ": unknown key '" + key +
                                "' (expected frames, seed, pose_noise_m, pose_noise_deg, rate_hz, "
                                "noise, hints or first)");
      }
    }
  }
  Status st = config.validate();
  if (!st.is_ok()) return st.with_context(context);
  return config;
}

}  // namespace synthetic

Result<std::unique_ptr<FrameSource>> open_synthetic_source(const std::string& arg,
                                                           const AppConfig& config) {
  synthetic::SyntheticConfig base;
  if (const DeviceCalibration* cal = config.calibration_for("synthetic"))
    base.intrinsics = cal->intrinsics;
  Result<synthetic::SyntheticConfig> parsed = synthetic::parse_synthetic_spec(arg, base);
  if (!parsed.is_ok()) return parsed.status();
  Result<synthetic::SyntheticSequence> sequence =
      synthetic::SyntheticSequence::create(parsed.value());
  if (!sequence.is_ok()) return sequence.status();
  return std::unique_ptr<FrameSource>(
      std::make_unique<synthetic::SyntheticSource>(std::move(sequence).value()));
}

}  // namespace depthfuse
