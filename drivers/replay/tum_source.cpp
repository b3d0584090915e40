#include "depthfuse/replay/tum_source.hpp"

#include <cmath>
#include <cstring>
#include <filesystem>
#include <numeric>
#include <sstream>

#include <opencv2/core.hpp>
#include <toml++/toml.h>

#include "depthfuse/base/log.hpp"
#include "depthfuse/input_file.hpp"
#include "depthfuse/trajectory.hpp"
#include "image_file.hpp"

DF_LOG_CATEGORY(Tum)

namespace fs = std::filesystem;

namespace depthfuse::replay {

namespace {

// The largest depth PNG a folder without camera.toml may hold, px a side: its first image sets the
// size, and a file claiming more is refused before it is decoded.
constexpr int kMaxUncalibratedSide = 4096;

struct ListEntry {
  double t = 0;
  std::string path;
};

// "timestamp path" lines; '#' comments.
Result<std::vector<ListEntry>> read_list(const std::string& path) {
  // fr1/xyz's lists are 30 KB; an hour at 30 Hz about 2 MB.
  auto text = read_input_file(path, "list", size_t{256} << 20);
  if (!text) return text.status();
  std::istringstream in(*text);
  std::vector<ListEntry> out;
  std::string line;
  size_t n = 0;
  while (std::getline(in, line)) {
    ++n;
    if (!line.empty() && line.back() == '\r') line.pop_back();
    const size_t first = line.find_first_not_of(" \t");
    if (first == std::string::npos || line[first] == '#') continue;
    std::istringstream ls(line);
    ListEntry e;
    std::string t;
    if (!(ls >> t >> e.path))
      return invalid_argument(path + ":" + std::to_string(n) + ": expected 'timestamp path'");
    char* end = nullptr;
    e.t = std::strtod(t.c_str(), &end);
    if (end == t.c_str() || *end || !std::isfinite(e.t))
      return invalid_argument(path + ":" + std::to_string(n) + ": bad timestamp '" + t + "'");
    out.push_back(e);
  }
  return out;
}

// Nearest entry in time within max_dt, or -1.
long nearest(const std::vector<ListEntry>& v, double t, double max_dt) {
  long best = -1;
  double best_dt = max_dt;
  auto it = std::lower_bound(v.begin(), v.end(), t,
                             [](const ListEntry& e, double x) { return e.t < x; });
  for (auto c : {it, it == v.begin() ? it : it - 1}) {
    if (c == v.end()) continue;
    const double dt = std::abs(c->t - t);
    if (dt <= best_dt) {
      best_dt = dt;
      best = static_cast<long>(c - v.begin());
    }
  }
  return best;
}

}  // namespace

Result<CameraFile> read_camera_file(const std::string& path) {
  auto text = read_input_file(path, "camera file", size_t{1} << 20);
  if (!text) return text.status();
  toml::table t;
  try {
    t = toml::parse(*text, path);
  } catch (const toml::parse_error& e) {
    std::ostringstream m;
    m << path << ":" << e.source().begin.line << ": " << e.description();
    return invalid_argument(m.str());
  }
  const toml::table* cam = t["camera"].as_table();
  if (!cam) return invalid_argument(path + ": no [camera] table");
  CameraFile out;
  for (auto&& [key, node] : *cam) {
    const std::string k(key.str());
    const std::string where = path + ":" + std::to_string(node.source().begin.line) + ": camera." + k;
    const std::optional<double> v = node.value<double>();
    if (!v) return invalid_argument(where + ": expected a number");
    if (k == "k1" || k == "k2" || k == "p1" || k == "p2" || k == "k3") {
      // Any sign; whether they describe a lens is checked on the map they make (Undistorter).
      if (!std::isfinite(*v)) return invalid_argument(where + ": must be finite");
      LensDistortion& d = out.distortion ? *out.distortion : out.distortion.emplace();
      (k == "k1" ? d.k1 : k == "k2" ? d.k2 : k == "p1" ? d.p1 : k == "p2" ? d.p2 : d.k3) = *v;
      continue;
    }
    if (k == "color_stamp_offset_s") {
      // Any sign; more than a second apart, the two streams are not of one scene.
      if (!(std::fabs(*v) <= 1.0)) return invalid_argument(where + ": must be in [-1, 1] s");
      out.color_stamp_offset_s = *v;
      continue;
    }
    if (k == "row_readout_s") {
      // 0 is a global shutter; a rolling shutter reads its rows within a frame period.
      if (!(*v >= 0.0 && *v <= 1.0)) return invalid_argument(where + ": must be in [0, 1] s");
      out.intrinsics.row_readout_s = *v;
      continue;
    }
    if (!(*v > 0) || !std::isfinite(*v)) return invalid_argument(where + ": must be > 0");
    if (k == "width") out.intrinsics.width = static_cast<int>(*v);
    else if (k == "height") out.intrinsics.height = static_cast<int>(*v);
    else if (k == "fx") out.intrinsics.fx = *v;
    else if (k == "fy") out.intrinsics.fy = *v;
    else if (k == "cx") out.intrinsics.cx = *v;
    else if (k == "cy") out.intrinsics.cy = *v;
    else if (k == "depth_scale") out.depth_scale = *v;
    else return invalid_argument(where + ": unknown key");
  }
  // Physical ranges: values that parse but describe no camera would give an empty cloud and exit 0.
  const CameraIntrinsics& k = out.intrinsics;
  auto refuse = [&](const std::string& what) { return invalid_argument(path + ": camera." + what); };
  if (k.width > kMaxUncalibratedSide || k.height > kMaxUncalibratedSide)
    return refuse("width x height " + std::to_string(k.width) + "x" + std::to_string(k.height) +
                  " is more than " + std::to_string(kMaxUncalibratedSide) + " px a side");
  if (auto problem = k.physical_problem()) return refuse(*problem);
  if (!(out.depth_scale >= 1.0 && out.depth_scale <= 1e6))
    return refuse("depth_scale " + std::to_string(out.depth_scale) +
                  " is not a PNG count per metre in [1, 1e6] (TUM: 5000, Kinect: 1000)");
  if (out.distortion) {
    // Refused here, with the file's name, rather than when a folder is opened with it.
    auto u = Undistorter::create(k, *out.distortion);
    if (!u) return invalid_argument(path + ": camera.k1..k3: " + u.status().message());
  }
  return out;
}

namespace {

// The folder's camera.toml, if it has one.
Result<std::optional<CameraFile>> folder_camera_file(const std::string& folder) {
  if (!fs::exists(folder + "/camera.toml")) return std::optional<CameraFile>();
  auto c = read_camera_file(folder + "/camera.toml");
  if (!c) return c.status();
  return std::optional<CameraFile>(std::move(*c));
}

// The colour list, on the depth's clock (the stamp offset added) and in time order; empty when
// colour is not wanted or the folder has none.
Result<std::vector<ListEntry>> colour_list(const std::string& folder, const TumReplayConfig& config,
                                           const std::optional<CameraFile>& cam) {
  std::vector<ListEntry> rgb_list;
  if (!config.load_color || !fs::exists(folder + "/rgb.txt")) return rgb_list;
  auto r = read_list(folder + "/rgb.txt");
  if (!r) return r.status();
  rgb_list = std::move(*r);
  const double offset_s = config.color_stamp_offset_s ? *config.color_stamp_offset_s
                          : cam                       ? cam->color_stamp_offset_s
                                                      : 0.0;
  for (ListEntry& e : rgb_list) e.t += offset_s;
  std::sort(rgb_list.begin(), rgb_list.end(), [](auto& a, auto& b) { return a.t < b.t; });
  return rgb_list;
}

// The caller's trajectory, else the folder's ground truth when it is to be used; none without
// either.
Result<std::optional<std::vector<StampedPose>>> pose_list(const std::string& folder,
                                                          const TumReplayConfig& config) {
  std::string poses_path = config.poses_path;
  if (poses_path.empty() && config.use_groundtruth && fs::exists(folder + "/groundtruth.txt"))
    poses_path = folder + "/groundtruth.txt";
  if (poses_path.empty()) return std::optional<std::vector<StampedPose>>();
  auto p = read_tum_trajectory(poses_path);
  if (!p) return p.status();
  return std::optional<std::vector<StampedPose>>(std::move(*p));
}

// The camera a folder's frames are read with, where it came from, and its lens.
struct Calibration {
  CameraIntrinsics intrinsics;
  std::string origin;
  std::optional<LensDistortion> distortion;
};

// Defaults for a folder without a camera: the TUM benchmark's for 640x480, else the Kinect V2's
// field of view at the first depth image's size.
Result<Calibration> default_calibration(const std::string& first_depth_path) {
  auto file = read_image_file(first_depth_path);
  if (!file) return file.status();
  auto first = decode_depth_image(*file, kMaxUncalibratedSide, kMaxUncalibratedSide);
  if (!first) return first.status();
  const int w = first->cols, h = first->rows;
  Calibration cal;
  if (w == 640 && h == 480) {
    // The TUM benchmark's default for its Kinect (v1) depth: fx = fy = 525, centre 319.5, 239.5.
    cal.intrinsics = {640, 480, 525.0, 525.0, 319.5, 239.5};
    cal.origin = "TUM default for 640x480";
  } else {
    CameraIntrinsics k = CameraIntrinsics::kinect_v2();
    // Scale the Kinect V2 field of view to the folder's own size.
    const double s = static_cast<double>(w) / k.width;
    cal.intrinsics = {w, h, k.fx * s, k.fy * s, (w - 1) / 2.0, (h - 1) / 2.0};
    cal.origin = "Kinect V2 default";
  }
  return cal;
}

// Intrinsics: the caller's, else camera.toml, else defaults for the image's own size.
Result<Calibration> calibration(const TumReplayConfig& config, const std::optional<CameraFile>& cam,
                                const std::string& first_depth_path) {
  if (config.intrinsics) return Calibration{*config.intrinsics, "caller", config.distortion};
  if (cam) return Calibration{cam->intrinsics, "camera.toml", cam->distortion};
  return default_calibration(first_depth_path);
}

}  // namespace

Result<std::unique_ptr<TumSource>> TumSource::open(const std::string& folder,
                                                   const TumReplayConfig& config) {
  if (!fs::is_directory(folder)) return not_found("no such TUM folder: " + folder);
  auto src = std::unique_ptr<TumSource>(new TumSource());
  src->folder_ = folder;

  auto cam = folder_camera_file(folder);
  if (!cam) return cam.status();
  auto depth_list = read_list(folder + "/depth.txt");
  if (!depth_list) return depth_list.status().with_context("reading the depth list");
  if (depth_list->empty()) return invalid_argument(folder + "/depth.txt lists no frames: empty sequence");
  auto rgb_list = colour_list(folder, config, *cam);
  if (!rgb_list) return rgb_list.status();
  auto poses = pose_list(folder, config);
  if (!poses) return poses.status();
  src->has_poses_ = poses->has_value();

  const size_t stride = std::max<size_t>(1, config.stride);
  for (size_t i = 0; i < depth_list->size(); i += stride) {
    const ListEntry& d = (*depth_list)[i];
    Entry e;
    e.t_depth = d.t;
    e.depth_path = folder + "/" + d.path;
    const long c = nearest(*rgb_list, d.t, config.max_association_dt_s);
    if (c >= 0) e.rgb_path = folder + "/" + (*rgb_list)[c].path;
    if (*poses && !(*poses)->empty()) {
      const long p = nearest_pose(**poses, d.t, config.max_association_dt_s);
      if (p >= 0) e.T_world_cam = (**poses)[p].T_world_cam;
    }
    src->entries_.push_back(std::move(e));
    if (config.max_frames && src->entries_.size() >= config.max_frames) break;
  }

  src->depth_scale_ = config.depth_scale ? *config.depth_scale : *cam ? (*cam)->depth_scale : 5000.0;
  auto cal = calibration(config, *cam, src->entries_.front().depth_path);
  if (!cal) return cal.status();
  src->intrinsics_ = cal->intrinsics;
  src->intrinsics_origin_ = cal->origin;
  if (cal->distortion && !cal->distortion->is_zero()) {
    auto u = Undistorter::create(src->intrinsics_, *cal->distortion);
    if (!u) return u.status().with_context(folder);
    DF_LOG(Tum, Info) << folder << ": lens distortion undone on every frame (pixels moved by up to "
                      << u->max_shift_px() << " px)";
    src->undistort_ = std::move(*u);
  }
  if (src->undistort_) {
    src->pixel_source_ = src->undistort_->source();
  } else {
    src->pixel_source_.resize(static_cast<size_t>(src->intrinsics_.width) * src->intrinsics_.height);
    std::iota(src->pixel_source_.begin(), src->pixel_source_.end(), 0);
  }
  return src;
}

Result<Frame> TumSource::load(size_t i) const {
  if (i >= entries_.size()) return end_of_stream();
  const Entry& e = entries_[i];
  auto file = read_image_file(e.depth_path);
  if (!file) return file.status();
  auto img = decode_depth_image(*file, intrinsics_.width, intrinsics_.height);
  if (!img) return img.status();
  if (img->cols != intrinsics_.width || img->rows != intrinsics_.height)
    return invalid_argument(e.depth_path + " is " + std::to_string(img->cols) + "x" +
                            std::to_string(img->rows) + " but the camera is " +
                            std::to_string(intrinsics_.width) + "x" +
                            std::to_string(intrinsics_.height));
  Frame f;
  f.utime = static_cast<int64_t>(std::llround(e.t_depth * 1e6));
  f.sequence = static_cast<uint32_t>(i);
  f.sensor_serial = "replay";
  f.intrinsics = intrinsics_;
  f.depth = DepthImage(img->cols, img->rows);
  const float inv_scale = static_cast<float>(1.0 / depth_scale_);
  // The lookup is the camera's size (checked above), and decoded images are continuous.
  const uint16_t* in = img->ptr<uint16_t>(0);
  const std::vector<int32_t>& from = pixel_source_;
  for (size_t i = 0; i < from.size(); ++i)
    f.depth.depth_m[i] = from[i] == Undistorter::kOutside ? 0.0f : in[from[i]] * inv_scale;
  if (!e.rgb_path.empty()) {
    // Colour (PNG or JPEG) is used only where it is registered to depth pixel for pixel (the same
    // size); other colour images are not decoded.
    auto rgb_file = read_image_file(e.rgb_path);
    if (!rgb_file) return rgb_file.status();
    if (rgb_file->width != img->cols || rgb_file->height != img->rows) {
      // Depth alone is still good: fused without colour. Said once per sequence.
      if (!warned_color_size_.exchange(true))
        DF_LOG(Tum, Warning) << e.rgb_path << " is " << rgb_file->width << "x" << rgb_file->height
                             << ", its depth " << img->cols << "x" << img->rows
                             << ": colour must be registered to depth pixel for pixel; frames whose "
                                "colour is another size are used without it";
    } else {
      auto rgb = decode_color_image(*rgb_file, img->cols, img->rows);
      if (!rgb) return rgb.status();
      f.color.width = rgb->cols;
      f.color.height = rgb->rows;
      f.color.rgb.resize(static_cast<size_t>(rgb->cols) * rgb->rows * 3);
      // Registered to depth pixel for pixel, so it is read through the same lookup.
      const cv::Vec3b* rgb_in = rgb->ptr<cv::Vec3b>(0);
      for (size_t i = 0; i < from.size(); ++i) {
        uint8_t* px = &f.color.rgb[i * 3];
        if (from[i] == Undistorter::kOutside) {
          px[0] = px[1] = px[2] = 0;
          continue;
        }
        const cv::Vec3b& c = rgb_in[from[i]];
        px[0] = c[2];  // OpenCV is BGR
        px[1] = c[1];
        px[2] = c[0];
      }
    }
  }
  f.T_world_cam_hint = e.T_world_cam;
  return f;
}

Result<Frame> TumSource::next() {
  if (next_ >= entries_.size()) return end_of_stream();
  return load(next_++);
}

std::string TumSource::describe() const {
  return "tum:" + folder_ + " (" + std::to_string(entries_.size()) + " frames, " +
         std::to_string(intrinsics_.width) + "x" + std::to_string(intrinsics_.height) + ")";
}

std::optional<double> TumSource::nominal_rate_hz() const {
  if (entries_.size() < 2) return std::nullopt;
  const double span = entries_.back().t_depth - entries_.front().t_depth;
  if (span <= 0) return std::nullopt;
  return (entries_.size() - 1) / span;
}

Result<std::unique_ptr<FrameSource>> open_tum_source(const std::string& arg, const AppConfig&) {
  TumReplayConfig c;
  c.use_groundtruth = true;
  auto s = TumSource::open(arg, c);
  if (!s) return s.status();
  return std::unique_ptr<FrameSource>(std::move(s.value()));
}

}  // namespace depthfuse::replay
