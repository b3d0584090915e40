// A periodic checkpoint of a scan file with and without its pose graph: 40 changed chunks of 3000
// points (what a checkpoint of a walk rewrites) and 30 poses, then the same with a graph of
// `keyframes` keyframes (1500-point clouds) whose row every checkpoint rewrites (poses, loops, a
// deformation history of `versions` versions) and one keyframe appended per checkpoint. The
// ratio of the two is what the graph adds to a checkpoint.
#include <benchmark/benchmark.h>
#include <unistd.h>

#include <cstdio>
#include <filesystem>
#include <random>

#include "depthfuse/store/scan_store.hpp"

using namespace depthfuse;

namespace {

std::string temp_file() {
  return (std::filesystem::temp_directory_path() /
          ("bench-graph-store-" + std::to_string(::getpid()) + ".dfscan"))
      .string();
}

void remove_file(const std::string& path) {
  for (const char* suffix : {"", "-wal", "-shm"}) std::filesystem::remove(path + suffix);
}

Chunk make_chunk(std::mt19937& rng, size_t n) {
  std::uniform_real_distribution<float> u(0.0f, 0.5f);
  Chunk c;
  c.points_for_write().resize(n);
  for (size_t i = 0; i < n; ++i) {
    c.points_for_write().position_m[i] = Eigen::Vector3f(u(rng), u(rng), u(rng));
  }
  return c;
}

std::shared_ptr<const KeyframeCloud> make_cloud(std::mt19937& rng) {
  std::uniform_real_distribution<float> u(-2.0f, 2.0f);
  auto c = std::make_shared<KeyframeCloud>();
  for (int i = 0; i < 1500; ++i) {
    c->position_m.emplace_back(u(rng), u(rng), 2.0f + u(rng));
    c->normal.emplace_back(0.0f, 0.0f, -1.0f);
  }
  return c;
}

Pose pose_at(size_t k) {
  Pose T = Pose::Identity();
  T.translation() = Eigen::Vector3d(0.2 * static_cast<double>(k), 0.0, 1.4);
  return T;
}

// A graph of n keyframes, n / 20 loops and a deformation history of `versions` versions.
GraphCheckpoint make_graph(std::mt19937& rng, size_t n, size_t versions) {
  GraphCheckpoint g;
  for (size_t k = 0; k < n; ++k) {
    GraphKeyframe kf;
    kf.frame_id = static_cast<uint32_t>(10 * k + 1);
    kf.T_world_kf = pose_at(k);
    kf.cloud = make_cloud(rng);
    g.graph.keyframes.push_back(kf);
    g.deformation.keyframe_first_frame.push_back(kf.frame_id);
    if (k == 0) continue;
    PoseGraphEdge e;
    e.from = static_cast<uint32_t>(k - 1);
    e.to = static_cast<uint32_t>(k);
    e.T_from_to = pose_at(k - 1).inverse() * pose_at(k);
    g.graph.odometry.push_back(e);
    g.graph.odometry_covariance.push_back(Matrix6d::Identity() * 1e-6);
  }
  for (size_t l = 0; l + 20 < n; l += 20) {
    PoseGraphEdge e;
    e.from = static_cast<uint32_t>(l);
    e.to = static_cast<uint32_t>(n - 1 - l);
    e.kind = PoseGraphEdge::Kind::kLoop;
    g.graph.loops.push_back(e);
  }
  for (size_t v = 0; v < versions; ++v) {
    g.deformation.T_world_kf.emplace_back();
    for (size_t k = 0; k < n; ++k) g.deformation.T_world_kf.back().push_back(pose_at(k));
    g.deformation.max_motion_m.push_back(0.01);
  }
  g.graph.version = static_cast<uint32_t>(versions - 1);
  return g;
}

// state.range(0): keyframes in the graph (0: no graph); state.range(1): deformation versions.
void BM_Checkpoint(benchmark::State& state) {
  const size_t keyframes = static_cast<size_t>(state.range(0));
  const size_t versions = static_cast<size_t>(state.range(1));
  const std::string path = temp_file();
  remove_file(path);
  auto store = store::ScanStore::open(path, store::OpenMode::kCreate);
  if (!store) {
    state.SkipWithError(store.status().to_string().c_str());
    return;
  }
  std::mt19937 rng(3);
  std::vector<Chunk> chunks;
  for (int i = 0; i < 40; ++i) chunks.push_back(make_chunk(rng, 3000));
  GraphCheckpoint graph;
  if (keyframes > 0) graph = make_graph(rng, keyframes, versions);
  uint32_t frame = 0;
  bool first = true;
  for (auto _ : state) {
    // Not timed: the graph grows by a keyframe a checkpoint, as a walk's does.
    state.PauseTiming();
    if (keyframes > 0 && !first) {
      GraphKeyframe kf = graph.graph.keyframes.back();
      kf.frame_id = frame + 1;
      graph.graph.keyframes.push_back(kf);
      graph.deformation.keyframe_first_frame.push_back(kf.frame_id);
      graph.deformation.T_world_kf.back().push_back(kf.T_world_kf);
      PoseGraphEdge e = graph.graph.odometry.back();
      e.from++;
      e.to++;
      graph.graph.odometry.push_back(e);
      graph.graph.odometry_covariance.push_back(graph.graph.odometry_covariance.back());
    }
    state.ResumeTiming();
    Status st = (*store)->begin_checkpoint();
    for (size_t i = 0; st && i < chunks.size(); ++i)
      st = (*store)->write_chunk(ChunkKey{static_cast<int32_t>(i), 0, 0}, chunks[i]);
    for (int p = 0; st && p < 30; ++p) {
      store::PoseRecord r;
      r.frame_id = ++frame + static_cast<uint32_t>(10 * keyframes);
      st = (*store)->write_pose(r);
    }
    if (st && keyframes > 0) st = (*store)->write_graph(graph);
    if (!st) {
      state.SkipWithError(st.to_string().c_str());
      break;
    }
    store::CheckpointInfo info;
    info.last_frame_id = frame + static_cast<uint32_t>(10 * keyframes);
    info.frames_fused = info.last_frame_id;
    auto rec = (*store)->commit_checkpoint(info);
    if (!rec) {
      state.SkipWithError(rec.status().to_string().c_str());
      break;
    }
    first = false;
  }
  store->reset();
  remove_file(path);
}

}  // namespace

BENCHMARK(BM_Checkpoint)
    ->ArgNames({"keyframes", "versions"})
    ->Args({0, 1})
    ->Args({300, 1})
    ->Args({300, 10})
    ->Iterations(30)
    ->Unit(benchmark::kMillisecond);
BENCHMARK_MAIN();
