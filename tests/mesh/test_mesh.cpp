// `depthfuse export --mesh` and `reconstruct --mesh` on a small synthetic corner (4 frames): a PLY
// with vertex and face elements that Open3D reads, 95 % of the vertices within 5 mm of the scene's
// analytic planes, and no triangle bridging the corner's open side (every triangle's centroid near
// a plane). Bad mesh options are refused with a reason.
#include <gtest/gtest.h>

#include <algorithm>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <sstream>

#include "depthfuse/mesh/surface_mesh.hpp"
#include "depthfuse/mesh/triangle_mesh.hpp"
#include "depthfuse/ply.hpp"
#include "depthfuse/point_map.hpp"
#include "depthfuse/store/scan_store.hpp"
#include "depthfuse/synthetic/scene.hpp"
#include "store_test_util.hpp"

using namespace depthfuse;
using depthfuse::store::test::Proc;
using depthfuse::store::test::run;
using depthfuse::store::test::TempDir;

namespace {

const std::string kCli = DEPTHFUSE_CLI;

// Reads a mesh PLY as write_mesh_ply writes it (binary little-endian, float x y z, optional uchar
// colour, uchar-counted int lists); fails the test on anything else.
mesh::TriangleMesh read_mesh(const std::string& path) {
  mesh::TriangleMesh m;
  std::ifstream in(path, std::ios::binary);
  std::string line, header;
  size_t vertices = 0, faces = 0;
  bool color = false;
  while (std::getline(in, line) && line != "end_header") {
    header += line + "\n";
    std::istringstream ls(line);
    std::string a, b;
    ls >> a >> b;
    if (a == "element" && b == "vertex") ls >> vertices;
    if (a == "element" && b == "face") ls >> faces;
    if (line == "property uchar red") color = true;
  }
  EXPECT_NE(header.find("format binary_little_endian 1.0"), std::string::npos) << header;
  EXPECT_NE(header.find("property list uchar int vertex_indices"), std::string::npos) << header;
  for (size_t i = 0; i < vertices && in; ++i) {
    Eigen::Vector3f p;
    in.read(reinterpret_cast<char*>(p.data()), 12);
    m.vertex_m.push_back(p);
    if (color) {
      std::array<uint8_t, 3> c;
      in.read(reinterpret_cast<char*>(c.data()), 3);
      m.vertex_rgb.push_back(c);
    }
  }
  for (size_t i = 0; i < faces && in; ++i) {
    uint8_t n = 0;
    int32_t v[3];
    in.read(reinterpret_cast<char*>(&n), 1);
    EXPECT_EQ(n, 3) << "face " << i;
    in.read(reinterpret_cast<char*>(v), 12);
    for (int32_t k : v) EXPECT_TRUE(k >= 0 && static_cast<size_t>(k) < vertices) << "face " << i;
    m.triangles.push_back({static_cast<uint32_t>(v[0]), static_cast<uint32_t>(v[1]), static_cast<uint32_t>(v[2])});
  }
  EXPECT_TRUE(in) << path << " is shorter than its header says";
  in.peek();
  EXPECT_TRUE(in.eof()) << path << " has bytes after its faces";
  return m;
}

// The corner scene, its cloud from `reconstruct`, and that cloud as a real scan file, made once.
class MeshTest : public ::testing::Test {
 protected:
  static void SetUpTestSuite() {
    dir_ = new TempDir("mesh");
    const std::string data = dir_->file("corner");
    Proc s = run(kCli + " synth corner " + data + " --frames 4 --seed 3");
    ASSERT_EQ(s.code, 0) << s.output;
    Proc r = run(kCli + " reconstruct " + data + " --poses " + data + "/groundtruth.txt -o " +
                 dir_->file("cloud.ply") + " --iterations 0");
    ASSERT_EQ(r.code, 0) << r.output;

    std::ifstream in(data + "/scene.toml");
    std::stringstream text;
    text << in.rdbuf();
    auto scene = synthetic::Scene::parse_toml(text.str(), data + "/scene.toml");
    ASSERT_TRUE(scene) << scene.status().to_string();
    scene_ = new synthetic::Scene(std::move(*scene));

    auto cloud = read_ply(dir_->file("cloud.ply"));
    ASSERT_TRUE(cloud) << cloud.status().to_string();
    PointMap map;
    map.add_points(*cloud);
    auto st = store::ScanStore::open(scan(), store::OpenMode::kCreate);
    ASSERT_TRUE(st) << st.status().to_string();
    ASSERT_TRUE((*st)->begin_checkpoint());
    map.for_each_chunk([&](const ChunkKey& k, const Chunk& c) { ASSERT_TRUE((*st)->write_chunk(k, c)); });
    store::CheckpointInfo info;
    info.last_frame_id = 4;
    ASSERT_TRUE((*st)->commit_checkpoint(info));
  }
  static void TearDownTestSuite() {
    delete dir_;
    delete scene_;
  }
  static std::string scan() { return dir_->file("scan.db"); }

  // 95 % of the vertices within 5 mm of a plane; every triangle's centroid within 2 cm of one.
  static void expect_accurate(const mesh::TriangleMesh& m, const std::string& what) {
    ASSERT_GT(m.triangles.size(), 10000u) << what;
    std::vector<double> d(m.vertex_m.size());
    for (size_t i = 0; i < d.size(); ++i) d[i] = scene_->distance_m(m.vertex_m[i].cast<double>());
    const size_t within = static_cast<size_t>(std::count_if(d.begin(), d.end(), [](double v) { return v <= 0.005; }));
    EXPECT_GE(within, 0.95 * static_cast<double>(d.size())) << what << ": " << within << " of " << d.size();
    size_t bridging = 0;
    for (const auto& t : m.triangles) {
      const Eigen::Vector3f c = (m.vertex_m[t[0]] + m.vertex_m[t[1]] + m.vertex_m[t[2]]) / 3.0f;
      bridging += scene_->distance_m(c.cast<double>()) > 0.02;
    }
    EXPECT_EQ(bridging, 0u) << what << ": triangles whose centroid is over 2 cm from every plane";
  }

  static TempDir* dir_;
  static synthetic::Scene* scene_;
};
TempDir* MeshTest::dir_ = nullptr;
synthetic::Scene* MeshTest::scene_ = nullptr;

TEST_F(MeshTest, ExportMeshIsAValidPlyCloseToTheTruthWithoutBridges) {
  const std::string out = dir_->file("mesh.ply");
  const Proc r = run(kCli + " export " + scan() + " --mesh -o " + out + " --mesh-depth 8");
  ASSERT_EQ(r.code, 0) << r.output;
  EXPECT_NE(r.output.find("triangles with colour"), std::string::npos) << r.output;
  const mesh::TriangleMesh m = read_mesh(out);
  EXPECT_TRUE(m.has_color());
  expect_accurate(m, "export --mesh");

  // Without trimming, Poisson's closed surface does bridge: the check above can fail.
  mesh::TriangleMesh untrimmed;
  {
    auto cloud = read_ply(dir_->file("cloud.ply"));
    ASSERT_TRUE(cloud);
    mesh::MeshOptions o;
    o.depth = 7;  // coarser than above: only the lid is looked for
    o.trim_factor = 100.0;
    auto u = mesh::mesh_points(*cloud, o);
    ASSERT_TRUE(u) << u.status().to_string();
    size_t bridging = 0;
    for (const auto& t : u->triangles)
      bridging += scene_->distance_m(((u->vertex_m[t[0]] + u->vertex_m[t[1]] + u->vertex_m[t[2]]) / 3.0f).cast<double>()) > 0.02;
    EXPECT_GT(bridging, 100u) << "untrimmed Poisson should close the corner's open side";
  }

  // Open3D reads it as the same mesh.
  const Proc o3d = run("/usr/bin/python3 -c \"import sys, open3d as o3d; m = o3d.io.read_triangle_mesh(sys.argv[1]); "
                       "print('open3d', len(m.vertices), len(m.triangles), m.has_vertex_colors())\" " + out);
  ASSERT_EQ(o3d.code, 0) << o3d.output;
  EXPECT_NE(o3d.output.find("open3d " + std::to_string(m.vertex_m.size()) + " " +
                            std::to_string(m.triangles.size()) + " True"),
            std::string::npos)
      << o3d.output;
}

TEST_F(MeshTest, ReconstructMeshesTheBatchResult) {
  const std::string data = dir_->file("corner"), out = dir_->file("batch_mesh.ply");
  const Proc r = run(kCli + " reconstruct " + data + " --poses " + data + "/groundtruth.txt -o " +
                     dir_->file("batch.ply") + " --iterations 0 --mesh " + out + " --mesh-depth 8");
  ASSERT_EQ(r.code, 0) << r.output;
  EXPECT_NE(r.output.find("mesh: "), std::string::npos) << r.output;
  expect_accurate(read_mesh(out), "reconstruct --mesh");
}

TEST_F(MeshTest, BadOptionsAreRefusedWithAReason) {
  const std::string out = dir_->file("bad.ply");
  // A bad option exits 2 with the usage, as in every program; a mesh that cannot be made exits 1.
  struct Case {
    std::string args, says;
    int code;
  } cases[] = {
      {" --mesh -o " + out + " --mesh-depth 30", "--mesh-depth", 2},
      {" --mesh -o " + out + " --mesh-depth deep", "--mesh-depth", 2},
      {" --mesh -o " + out + " --mesh-trim 0", "--mesh-trim", 2},
      {" --mesh -o " + dir_->file("bad.pcd"), "must end in .ply", 2},
      {" -o " + out + " --mesh-depth 9", "without --mesh", 2},
      // The estimate is refused before Poisson runs, naming what it needs.
      {" --mesh -o " + out + " --mesh-memory-mb 1", "needs about", 1},
  };
  for (const Case& c : cases) {
    const Proc r = run(kCli + " export " + scan() + c.args);
    EXPECT_EQ(r.code, c.code) << c.args << ": " << r.output;
    EXPECT_NE(r.output.find(c.says), std::string::npos) << c.args << ": " << r.output;
    EXPECT_FALSE(std::filesystem::exists(out)) << c.args;
  }
  const Proc r = run(kCli + " reconstruct x -o y.ply --mesh-depth 9");
  EXPECT_EQ(r.code, 2) << r.output;
  EXPECT_NE(r.output.find("--mesh-depth without --mesh"), std::string::npos) << r.output;
}

}  // namespace
