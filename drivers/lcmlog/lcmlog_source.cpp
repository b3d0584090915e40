#include "depthfuse/lcmlog/lcmlog_source.hpp"

#include <lcm/eventlog.h>

#include <cerrno>
#include <cstdio>

#include "depthfuse/base/errno_text.hpp"
#include "depthfuse/color_frame_t.hpp"
#include "depthfuse/depth_frame_t.hpp"
#include "depthfuse/input_file.hpp"
#include "depthfuse/lcm/codec.hpp"
#include "depthfuse/lcm/frame_codec.hpp"
#include "depthfuse/lcm/message_auth.hpp"

namespace depthfuse::lcmlog {

namespace {

constexpr uint32_t kEventMagic = 0xEDA1DA01u;
constexpr size_t kHeaderBytes = 4 + 8 + 8 + 4 + 4;
// lcm_eventlog_read_next_event asserts on longer channel names; we reject them first.
constexpr int32_t kMaxChannelLength = 1000;

uint32_t be32(const uint8_t* p) {
  return (uint32_t(p[0]) << 24) | (uint32_t(p[1]) << 16) | (uint32_t(p[2]) << 8) | uint32_t(p[3]);
}
uint64_t be64(const uint8_t* p) { return (uint64_t(be32(p)) << 32) | be32(p + 4); }

lcm_eventlog_t* as_log(void* p) { return static_cast<lcm_eventlog_t*>(p); }

// A recorded message without the signature a rig with a key adds: the log is a file this host
// chose to read, not the bus, and its signatures are long stale.
size_t payload_size(const lcm_eventlog_event_t* ev) {
  return lcm::unsigned_payload_size(static_cast<const uint8_t*>(ev->data),
                                    static_cast<size_t>(ev->datalen));
}

enum class HeaderCheck { kOk, kEnd, kTruncated, kCorrupt };

// Validates the event header at `offset` so that LCM's reader is only ever handed a sane event
// (it asserts on long channel names and allocates whatever length a damaged header claims).
HeaderCheck check_header(std::FILE* f, long offset, long file_size, int32_t* channel_len) {
  if (offset >= file_size) return HeaderCheck::kEnd;
  if (file_size - offset < static_cast<long>(kHeaderBytes)) return HeaderCheck::kTruncated;
  uint8_t h[kHeaderBytes];
  if (std::fseek(f, offset, SEEK_SET) != 0 || std::fread(h, 1, kHeaderBytes, f) != kHeaderBytes)
    return HeaderCheck::kTruncated;
  if (be32(h) != kEventMagic) return HeaderCheck::kCorrupt;
  const int32_t clen = static_cast<int32_t>(be32(h + 20));
  const int32_t dlen = static_cast<int32_t>(be32(h + 24));
  if (clen <= 0 || clen >= kMaxChannelLength || dlen < 0) return HeaderCheck::kCorrupt;
  (void)be64;
  if (file_size - offset - static_cast<long>(kHeaderBytes) < static_cast<long>(clen) + dlen)
    return HeaderCheck::kTruncated;
  *channel_len = clen;
  return HeaderCheck::kOk;
}

// Next offset after `from` where the event marker appears, or file_size.
long resync(std::FILE* f, long from, long file_size) {
  if (std::fseek(f, from, SEEK_SET) != 0) return file_size;
  uint32_t window = 0;
  long pos = from;
  int c;
  while ((c = std::fgetc(f)) != EOF) {
    window = (window << 8) | static_cast<uint32_t>(c);
    ++pos;
    if (pos - from >= 4 && window == kEventMagic) return pos - 4;
  }
  return file_size;
}

}  // namespace

LcmLogSource::~LcmLogSource() {
  if (log_) lcm_eventlog_destroy(as_log(log_));
}

Result<std::unique_ptr<LcmLogSource>> LcmLogSource::open(const std::string& path,
                                                        const Options& options) {
  DF_RETURN_IF_ERROR(check_input_file(path, "LCM log"));
  lcm_eventlog_t* log = lcm_eventlog_create(path.c_str(), "r");
  if (!log) return io_error("cannot open LCM log '" + path + "': " + errno_text());
  std::unique_ptr<LcmLogSource> src(new LcmLogSource());
  src->path_ = path;
  src->options_ = options;
  src->log_ = log;
  DF_RETURN_IF_ERROR(src->index());
  if (src->depth_.empty()) {
    std::string why = "LCM log '" + path + "' has no usable depth frames on channel " +
                      options.depth_channel + " (" + std::to_string(src->stats_.events) +
                      " events";
    if (src->stats_.malformed) why += ", " + std::to_string(src->stats_.malformed) + " malformed";
    if (src->stats_.foreign) why += ", " + std::to_string(src->stats_.foreign) + " of another type";
    if (src->stats_.bad_version)
      why += ", " + std::to_string(src->stats_.bad_version) + " of an unknown protocol version";
    if (src->stats_.corrupt_regions) why += ", damaged";
    if (src->stats_.truncated) why += ", truncated";
    why += ")";
    if (!src->stats_.first_problem.empty()) why += "; the first refused: " + src->stats_.first_problem;
    return corrupt(why);
  }
  return src;
}

Status LcmLogSource::index() {
  std::FILE* f = as_log(log_)->f;
  if (std::fseek(f, 0, SEEK_END) != 0) return io_error("cannot seek in LCM log '" + path_ + "'");
  const long file_size = std::ftell(f);
  long offset = 0;
  depthfuse::depth_frame_t depth_msg;
  depthfuse::color_frame_t color_msg;
  for (;;) {
    int32_t clen = 0;
    const HeaderCheck hc = check_header(f, offset, file_size, &clen);
    if (hc == HeaderCheck::kEnd) break;
    if (hc == HeaderCheck::kTruncated) {
      stats_.truncated = true;
      break;
    }
    if (hc == HeaderCheck::kCorrupt) {
      ++stats_.corrupt_regions;
      offset = resync(f, offset + 1, file_size);
      continue;
    }
    std::fseek(f, offset, SEEK_SET);
    lcm_eventlog_event_t* ev = lcm_eventlog_read_next_event(as_log(log_));
    if (!ev) {
      stats_.truncated = true;
      break;
    }
    const long event_offset = offset;
    offset = std::ftell(f);
    ++stats_.events;
    const std::string channel(ev->channel, static_cast<size_t>(ev->channellen));
    if (channel == options_.depth_channel) {
      const auto r = lcm::decode_message(ev->data, payload_size(ev), &depth_msg);
      Frame probe;
      lcm::DepthFrameNotes notes;
      const Status decoded =
          r == lcm::DecodeResult::kOk
              ? lcm::decode_depth_frame(depth_msg, &probe, options_.limits, nullptr, &notes)
              : Status::ok();
      if (r == lcm::DecodeResult::kOk && decoded.is_ok()) {
        depth_.push_back({event_offset, ev->timestamp});
        ++stats_.depth_frames;
        if (!notes.pose_hint_refused.empty() && !stats_.pose_hints_refused++)
          stats_.first_pose_hint_refused = notes.pose_hint_refused;
      } else if (r == lcm::DecodeResult::kOk) {
        if (!stats_.malformed++) stats_.first_problem = decoded.message();
      } else if (r == lcm::DecodeResult::kForeign) {
        ++stats_.foreign;
      } else if (r == lcm::DecodeResult::kBadVersion) {
        ++stats_.bad_version;
      } else {
        ++stats_.malformed;
      }
    } else if (channel == options_.color_channel) {
      const auto r = lcm::decode_message(ev->data, payload_size(ev), &color_msg);
      if (r == lcm::DecodeResult::kOk) {
        color_by_sequence_[color_msg.sequence] = {event_offset, ev->timestamp};
        ++stats_.color_frames;
      } else if (r == lcm::DecodeResult::kForeign) {
        ++stats_.foreign;
      } else if (r == lcm::DecodeResult::kBadVersion) {
        ++stats_.bad_version;
      } else {
        ++stats_.malformed;
      }
    }
    lcm_eventlog_free_event(ev);
  }
  return Status::ok();
}

Result<std::vector<uint8_t>> LcmLogSource::read_payload(long offset) {
  std::FILE* f = as_log(log_)->f;
  if (std::fseek(f, offset, SEEK_SET) != 0)
    return io_error("cannot seek in LCM log '" + path_ + "'");
  lcm_eventlog_event_t* ev = lcm_eventlog_read_next_event(as_log(log_));
  if (!ev) return corrupt("LCM log '" + path_ + "' changed since it was opened");
  std::vector<uint8_t> data(static_cast<const uint8_t*>(ev->data),
                            static_cast<const uint8_t*>(ev->data) + payload_size(ev));
  lcm_eventlog_free_event(ev);
  return data;
}

Result<Frame> LcmLogSource::load(size_t i) {
  if (i >= depth_.size()) return end_of_stream();
  auto payload = read_payload(depth_[i].offset);
  if (!payload) return payload.status();
  depthfuse::depth_frame_t msg;
  if (lcm::decode_message(payload->data(), payload->size(), &msg) != lcm::DecodeResult::kOk)
    return corrupt("LCM log '" + path_ + "': depth frame " + std::to_string(i) +
                   " no longer decodes");
  Frame frame;
  DF_RETURN_IF_ERROR(lcm::decode_depth_frame(msg, &frame, options_.limits)
                         .with_context("LCM log '" + path_ + "'"));
  auto it = color_by_sequence_.find(msg.sequence);
  if (it != color_by_sequence_.end()) {
    auto cp = read_payload(it->second.offset);
    depthfuse::color_frame_t cmsg;
    ColorImage color;
    // A colour image that does not fit is dropped; the depth frame is still good.
    if (cp && lcm::decode_message(cp->data(), cp->size(), &cmsg) == lcm::DecodeResult::kOk &&
        lcm::decode_color_frame(cmsg, &color, options_.limits).is_ok() && color.width == frame.depth.width &&
        color.height == frame.depth.height)
      frame.color = std::move(color);
  }
  return frame;
}

Result<Frame> LcmLogSource::next() {
  if (next_ >= depth_.size()) return end_of_stream();
  return load(next_++);
}

std::string LcmLogSource::describe() const {
  std::string d = "lcmlog:" + path_ + " (" + std::to_string(depth_.size()) + " frames";
  if (stats_.malformed + stats_.foreign + stats_.bad_version)
    d += ", " + std::to_string(stats_.malformed + stats_.foreign + stats_.bad_version) +
         " unusable events";
  if (stats_.truncated) d += ", truncated";
  if (stats_.pose_hints_refused)
    d += ", " + std::to_string(stats_.pose_hints_refused) +
         " without their pose hint: " + stats_.first_pose_hint_refused;
  return d + ")";
}

std::optional<double> LcmLogSource::nominal_rate_hz() const {
  if (depth_.size() < 2) return std::nullopt;
  const double span_s = (depth_.back().log_utime - depth_.front().log_utime) * 1e-6;
  if (!(span_s > 0)) return std::nullopt;
  return static_cast<double>(depth_.size() - 1) / span_s;
}

Result<std::unique_ptr<FrameSource>> open_lcmlog_source(const std::string& arg,
                                                        const AppConfig& config) {
  std::string path = arg;
  LcmLogSource::Options options;
  options.limits.max_width = config.fusion.max_frame_width;
  options.limits.max_height = config.fusion.max_frame_height;
  options.limits.max_pose_hint_m = config.fusion.workspace_radius_m;
  if (const auto q = arg.find('?'); q != std::string::npos) {
    path = arg.substr(0, q);
    const std::string query = arg.substr(q + 1);
    size_t pos = 0;
    while (pos < query.size()) {
      const auto amp = query.find('&', pos);
      const std::string kv = query.substr(pos, amp == std::string::npos ? std::string::npos : amp - pos);
      const auto eq = kv.find('=');
      const std::string key = kv.substr(0, eq);
      const std::string value = eq == std::string::npos ? "" : kv.substr(eq + 1);
      if (key == "depth_channel" && !value.empty())
        options.depth_channel = value;
      else if (key == "color_channel" && !value.empty())
        options.color_channel = value;
      else
        return invalid_argument("lcmlog source '" + arg + "': unknown option '" + kv +
                                "' (expected depth_channel=NAME or color_channel=NAME)");
      if (amp == std::string::npos) break;
      pos = amp + 1;
    }
  }
  if (path.empty()) return invalid_argument("lcmlog source needs a file: lcmlog:<file>");
  auto src = LcmLogSource::open(path, options);
  if (!src) return src.status();
  return std::unique_ptr<FrameSource>(std::move(src).value());
}

}  // namespace depthfuse::lcmlog
