// Image files of recorded sequences (see image_file.hpp). PNG through OpenCV; JPEG through
// libturbojpeg, Debian's JPEG library (OpenCV's own JPEG reader is built on it too), whose header
// call gives the size without decoding.
#include "image_file.hpp"

#include <turbojpeg.h>

#include <cstdint>
#include <cstring>
#include <memory>

#include <opencv2/imgcodecs.hpp>

#include "depthfuse/input_file.hpp"

namespace depthfuse::replay {
namespace {

// A 4096 x 4096 16-bit PNG stored without compression is 32 MiB; no image file of a sequence is
// larger.
constexpr size_t kMaxImageFileBytes = size_t{64} << 20;

const char* format_name(ImageFormat f) { return f == ImageFormat::kPng ? "PNG" : "JPEG"; }

struct TjHandle {
  tjhandle handle = tjInitDecompress();
  ~TjHandle() {
    if (handle) tjDestroy(handle);
  }
};

// A PNG's width and height, from its IHDR chunk (the first after the signature).
Status png_header(ImageFile* f) {
  const auto* h = reinterpret_cast<const unsigned char*>(f->bytes.data());
  if (f->bytes.size() < 24 || std::memcmp(h + 12, "IHDR", 4) != 0)
    return corrupt("cannot decode " + f->path + ": a PNG without its header");
  auto be32 = [](const unsigned char* p) {
    return (uint32_t{p[0]} << 24) | (uint32_t{p[1]} << 16) | (uint32_t{p[2]} << 8) | p[3];
  };
  const uint32_t w = be32(h + 16), ht = be32(h + 20);
  if (w == 0 || ht == 0 || w > INT32_MAX || ht > INT32_MAX)
    return corrupt("cannot decode " + f->path + ": PNG size " + std::to_string(w) + "x" +
                   std::to_string(ht) + " is invalid");
  f->width = static_cast<int>(w);
  f->height = static_cast<int>(ht);
  return Status::ok();
}

Status jpeg_header(ImageFile* f) {
  TjHandle tj;
  if (!tj.handle) return internal_error("cannot start the JPEG decoder: " + std::string(tjGetErrorStr()));
  int subsampling = 0, colorspace = 0;
  if (tjDecompressHeader3(tj.handle, reinterpret_cast<const unsigned char*>(f->bytes.data()),
                          static_cast<unsigned long>(f->bytes.size()), &f->width, &f->height,
                          &subsampling, &colorspace) != 0)
    return corrupt("cannot decode " + f->path + ": " + tjGetErrorStr2(tj.handle));
  if (f->width <= 0 || f->height <= 0)
    return corrupt("cannot decode " + f->path + ": JPEG size " + std::to_string(f->width) + "x" +
                   std::to_string(f->height) + " is invalid");
  return Status::ok();
}

Status check_size(const ImageFile& f, int max_width, int max_height) {
  if (f.width > max_width || f.height > max_height)
    return corrupt(f.path + " declares " + std::to_string(f.width) + "x" +
                   std::to_string(f.height) + " pixels, more than the " +
                   std::to_string(max_width) + "x" + std::to_string(max_height) + " expected");
  return Status::ok();
}

Result<cv::Mat> decode_png(const ImageFile& f, int flags) {
  cv::Mat img;
  try {
    const cv::Mat encoded(1, static_cast<int>(f.bytes.size()), CV_8UC1,
                          const_cast<char*>(f.bytes.data()));
    img = cv::imdecode(encoded, flags);
  } catch (const cv::Exception& e) {
    return corrupt("cannot decode " + f.path + ": " + e.what());
  }
  if (img.empty()) return corrupt("cannot decode " + f.path + " (corrupt or not an image)");
  return img;
}

}  // namespace

Result<ImageFile> read_image_file(const std::string& path) {
  auto bytes = read_input_file(path, "image", kMaxImageFileBytes);
  if (!bytes) {
    if (bytes.status().code() == StatusCode::kNotFound) return not_found("missing image " + path);
    return bytes.status();
  }
  ImageFile f;
  f.path = path;
  f.bytes = std::move(*bytes);
  static const unsigned char kPng[8] = {0x89, 'P', 'N', 'G', '\r', '\n', 0x1a, '\n'};
  const auto* b = reinterpret_cast<const unsigned char*>(f.bytes.data());
  if (f.bytes.size() >= 8 && std::memcmp(b, kPng, 8) == 0) {
    f.format = ImageFormat::kPng;
    DF_RETURN_IF_ERROR(png_header(&f));
  } else if (f.bytes.size() >= 3 && b[0] == 0xFF && b[1] == 0xD8 && b[2] == 0xFF) {
    f.format = ImageFormat::kJpeg;
    DF_RETURN_IF_ERROR(jpeg_header(&f));
  } else {
    return corrupt("cannot decode " + path + ": neither a PNG nor a JPEG");
  }
  return f;
}

Result<cv::Mat> decode_depth_image(const ImageFile& f, int max_width, int max_height) {
  if (f.format != ImageFormat::kPng)
    return corrupt(f.path + ": depth must be a 16-bit single-channel PNG, not a " +
                   format_name(f.format));
  DF_RETURN_IF_ERROR(check_size(f, max_width, max_height));
  auto img = decode_png(f, cv::IMREAD_UNCHANGED);
  if (!img) return img.status();
  if (img->type() != CV_16UC1)
    return corrupt(f.path + ": depth must be a 16-bit single-channel PNG");
  return img;
}

Result<cv::Mat> decode_color_image(const ImageFile& f, int max_width, int max_height) {
  DF_RETURN_IF_ERROR(check_size(f, max_width, max_height));
  if (f.format == ImageFormat::kPng) return decode_png(f, cv::IMREAD_COLOR);
  TjHandle tj;
  if (!tj.handle) return internal_error("cannot start the JPEG decoder: " + std::string(tjGetErrorStr()));
  cv::Mat bgr(f.height, f.width, CV_8UC3);
  if (tjDecompress2(tj.handle, reinterpret_cast<const unsigned char*>(f.bytes.data()),
                    static_cast<unsigned long>(f.bytes.size()), bgr.data, f.width,
                    static_cast<int>(bgr.step[0]), f.height, TJPF_BGR, 0) != 0 &&
      tjGetErrorCode(tj.handle) == TJERR_FATAL)
    return corrupt("cannot decode " + f.path + ": " + tjGetErrorStr2(tj.handle));
  return bgr;
}

}  // namespace depthfuse::replay
