// Helpers shared by the synthetic source tests.
#pragma once

#include <gtest/gtest.h>
#include <unistd.h>

#include <Eigen/Core>
#include <cmath>
#include <cstdlib>
#include <filesystem>
#include <string>

#include "depthfuse/types.hpp"

namespace depthfuse::synthetic::testing {

// The world point seen at pixel (u, v) with depth z.
inline Eigen::Vector3d backproject(const CameraIntrinsics& K, const Pose& T_world_cam, int u, int v,
                                   double z) {
  const Eigen::Vector3d p_cam(z * (u - K.cx) / K.fx, z * (v - K.cy) / K.fy, z);
  return T_world_cam * p_cam;
}

// A fresh, empty folder for one test, removed when the object goes away.
class TempDir {
 public:
  TempDir() {
    const auto* info = ::testing::UnitTest::GetInstance()->current_test_info();
    std::string name =
        std::string("depthfuse_synthetic_") + info->test_suite_name() + "_" + info->name();
    for (char& c : name)
      if (c == '/') c = '_';
    path_ = std::filesystem::temp_directory_path() / (name + "_" + std::to_string(::getpid()));
    std::filesystem::remove_all(path_);
    std::filesystem::create_directories(path_);
  }
  ~TempDir() {
    std::error_code ec;
    std::filesystem::remove_all(path_, ec);
  }
  const std::filesystem::path& path() const { return path_; }

 private:
  std::filesystem::path path_;
};

}  // namespace depthfuse::synthetic::testing
