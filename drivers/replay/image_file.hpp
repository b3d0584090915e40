// A recorded sequence's image files: PNG (depth, colour) and JPEG (colour, as many RGB-D datasets
// ship it). A file is read whole through InputFile (a regular file only: a FIFO named in a list
// must not block the replay), and the size its header declares is checked against the caller's
// limit before anything is decoded, so that a small file claiming a huge image costs nothing.
#pragma once

#include <string>

#include <opencv2/core.hpp>

#include "depthfuse/status.hpp"

namespace depthfuse::replay {

enum class ImageFormat { kPng, kJpeg };

struct ImageFile {
  std::string path;
  std::string bytes;
  ImageFormat format = ImageFormat::kPng;
  int width = 0;   // as its header declares
  int height = 0;
};

// Reads `path` and its header. Errors name the file: missing, not a regular file, neither PNG nor
// JPEG, a header that declares no image.
Result<ImageFile> read_image_file(const std::string& path);

// Decodes a 16-bit single-channel PNG (depth counts) no larger than max_width x max_height.
Result<cv::Mat> decode_depth_image(const ImageFile& image, int max_width, int max_height);

// Decodes colour, PNG or JPEG, no larger than max_width x max_height, to 8-bit BGR (OpenCV's
// order, as imread gives it).
Result<cv::Mat> decode_color_image(const ImageFile& image, int max_width, int max_height);

}  // namespace depthfuse::replay
