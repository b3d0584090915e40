// Reads a cloud written by `depthfuse export` with PCL (io only) and compares it with a reference
// text file of "x y z nx ny nz r g b" lines. Exit 0 and "ok <n>" when every point matches exactly.
// Usage: store_pcl_read_check <cloud.pcd|cloud.ply> <reference.txt>
#include <pcl/io/pcd_io.h>
#include <pcl/io/ply_io.h>
#include <pcl/point_types.h>

#include <cstdio>
#include <fstream>
#include <string>
#include <vector>

int main(int argc, char** argv) {
  if (argc != 3) {
    std::fprintf(stderr, "usage: %s <cloud.pcd|cloud.ply> <reference.txt>\n", argv[0]);
    return 2;
  }
  const std::string path = argv[1];
  pcl::PointCloud<pcl::PointXYZRGBNormal> cloud;
  const bool ply = path.size() > 4 && path.substr(path.size() - 4) == ".ply";
  const int rc = ply ? pcl::io::loadPLYFile(path, cloud) : pcl::io::loadPCDFile(path, cloud);
  if (rc != 0) {
    std::fprintf(stderr, "PCL cannot read %s (%d)\n", path.c_str(), rc);
    return 1;
  }
  std::ifstream ref(argv[2]);
  std::vector<std::vector<float>> want;
  for (float v[9]; ref >> v[0] >> v[1] >> v[2] >> v[3] >> v[4] >> v[5] >> v[6] >> v[7] >> v[8];)
    want.emplace_back(v, v + 9);
  if (want.size() != cloud.size()) {
    std::fprintf(stderr, "%s: PCL read %zu points, expected %zu\n", path.c_str(), cloud.size(), want.size());
    return 1;
  }
  for (size_t i = 0; i < want.size(); ++i) {
    const auto& p = cloud[i];
    const float got[9] = {p.x, p.y, p.z, p.normal_x, p.normal_y, p.normal_z,
                          static_cast<float>(p.r), static_cast<float>(p.g), static_cast<float>(p.b)};
    for (int k = 0; k < 9; ++k) {
      if (got[k] != want[i][k]) {
        std::fprintf(stderr, "%s: point %zu field %d is %.9g, expected %.9g\n", path.c_str(), i, k,
                     got[k], want[i][k]);
        return 1;
      }
    }
  }
  std::printf("ok %zu\n", cloud.size());
  return 0;
}
