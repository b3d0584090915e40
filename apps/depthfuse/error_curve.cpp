#include "error_curve.hpp"

#include <cstdio>

#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>

namespace depthfuse::cli {

Status write_cumulative_csv(const std::string& path, const DistanceSummary& s, double step_m, double max_m) {
  std::FILE* f = std::fopen(path.c_str(), "w");
  if (!f) return io_error("cannot create " + path);
  std::fprintf(f, "error_m,fraction_of_points\n");
  for (double e = 0; e <= max_m + 1e-12; e += step_m) std::fprintf(f, "%.4f,%.6f\n", e, fraction_within(s, e));
  if (std::fclose(f) != 0) return io_error("cannot write " + path);
  return Status::ok();
}

Status write_cumulative_png(const std::string& path,
                            const std::vector<std::pair<std::string, const DistanceSummary*>>& curves,
                            double max_m) {
  const int W = 800, H = 500, L = 70, R = 20, T = 20, B = 60;
  cv::Mat img(H, W, CV_8UC3, cv::Scalar(255, 255, 255));
  auto X = [&](double e) { return static_cast<int>(L + (W - L - R) * e / max_m); };
  auto Y = [&](double f) { return static_cast<int>(H - B - (H - T - B) * f); };
  for (int i = 0; i <= 10; ++i) {
    const double f = i / 10.0, e = max_m * i / 10.0;
    cv::line(img, {L, Y(f)}, {W - R, Y(f)}, cv::Scalar(230, 230, 230));
    cv::line(img, {X(e), T}, {X(e), H - B}, cv::Scalar(230, 230, 230));
    char buf[32];
    std::snprintf(buf, sizeof buf, "%.0f%%", f * 100);
    cv::putText(img, buf, {5, Y(f) + 5}, cv::FONT_HERSHEY_SIMPLEX, 0.4, cv::Scalar(0, 0, 0));
    std::snprintf(buf, sizeof buf, "%.0f", e * 1000);
    cv::putText(img, buf, {X(e) - 8, H - B + 18}, cv::FONT_HERSHEY_SIMPLEX, 0.4, cv::Scalar(0, 0, 0));
  }
  cv::putText(img, "distance to ground truth [mm]", {W / 2 - 120, H - 15}, cv::FONT_HERSHEY_SIMPLEX, 0.5, cv::Scalar(0, 0, 0));
  const cv::Scalar colors[] = {{200, 60, 30}, {40, 150, 40}, {30, 30, 200}, {160, 40, 160}, {20, 140, 200}, {90, 90, 90}};
  for (size_t c = 0; c < curves.size(); ++c) {
    std::vector<cv::Point> pts;
    for (int i = 0; i <= 400; ++i) {
      const double e = max_m * i / 400;
      pts.push_back({X(e), Y(fraction_within(*curves[c].second, e))});
    }
    const cv::Scalar col = colors[c % 6];
    cv::polylines(img, pts, false, col, 2, cv::LINE_AA);
    cv::putText(img, curves[c].first, {W - R - 220, H - B - 20 - 22 * static_cast<int>(c)}, cv::FONT_HERSHEY_SIMPLEX, 0.5, col, 1, cv::LINE_AA);
  }
  try {
    if (!cv::imwrite(path, img)) return io_error("cannot write " + path);
  } catch (const cv::Exception& e) {
    return io_error("cannot write " + path + ": " + e.what());
  }
  return Status::ok();
}

}  // namespace depthfuse::cli
