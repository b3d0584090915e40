// One 512x424 depth packet through depthfuse's decoder and, where libfreenect2 and its source
// are at hand, through libfreenect2's CPU decoder: side by side in one run, with the ratio.
//   build/bin/bench_kinect2_decode [--benchmark_format=json]   (the ratios then go to stderr)
// Packets are encoded from the synthetic scene of the decoder tests (both filters on, the
// driver's default). BM_DecodeDepth/depthfuse is one thread, as libfreenect2's.
#include <cstdio>
#include <map>
#include <string>

#include <benchmark/benchmark.h>

#include "decoder_scene.hpp"
#include "depthfuse/kinect2/depth_decoder.hpp"
#include "depthfuse/kinect2/packet_encoder.hpp"
#ifdef DF_HAVE_FREENECT2_REFERENCE
#include "freenect2_reference.hpp"
#endif

namespace depthfuse::kinect2 {
namespace {

const std::vector<uint8_t>& scene_packet() {
  static const std::vector<uint8_t> packet = [] {
    std::vector<uint8_t> bytes;
    const test::SceneImages scene = test::scene_images();
    auto encoder = PacketEncoder::create(simulated_p0_tables(), simulated_ir_calibration());
    if (!encoder.is_ok() || !encoder.value()->encode(scene.depth, scene.ir, &bytes).is_ok())
      std::abort();
    return bytes;
  }();
  return packet;
}

void decode_depthfuse(benchmark::State& state, int threads, bool filters) {
  DepthDecoderOptions options;
  options.threads = threads;
  options.bilateral_filter = filters;
  options.edge_aware_filter = filters;
  auto decoder = DepthDecoder::create(simulated_p0_tables(), simulated_ir_calibration(), options);
  if (!decoder.is_ok()) {
    state.SkipWithError(decoder.status().to_string().c_str());
    return;
  }
  const std::vector<uint8_t>& packet = scene_packet();
  DepthImage depth;
  IrImage ir;
  uint32_t sequence = 0;
  for (auto _ : state) {
    const Status s = decoder.value()->decode(
        RawDepthPacket{++sequence, 0, packet.data(), packet.size()}, &depth, &ir);
    benchmark::DoNotOptimize(s);
    benchmark::DoNotOptimize(depth.depth_m.data());
  }
}

void encode(benchmark::State& state) {
  const test::SceneImages scene = test::scene_images();
  auto encoder = PacketEncoder::create(simulated_p0_tables(), simulated_ir_calibration());
  std::vector<uint8_t> packet;
  for (auto _ : state) {
    const Status s = encoder.value()->encode(scene.depth, scene.ir, &packet);
    benchmark::DoNotOptimize(s);
  }
}

#ifdef DF_HAVE_FREENECT2_REFERENCE
void decode_libfreenect2(benchmark::State& state, bool filters) {
  test::Freenect2CpuDecoder decoder(simulated_p0_tables(), simulated_ir_calibration(), 0.5f, 4.5f,
                                    filters, filters);
  std::vector<uint8_t> packet = scene_packet();
  std::vector<float> depth_mm, ir;
  uint32_t sequence = 0;
  for (auto _ : state) {
    decoder.decode(&packet, ++sequence, &depth_mm, &ir);
    benchmark::DoNotOptimize(depth_mm.data());
  }
}
#endif

// Reports as --benchmark_format asks (through the library's own reporter), then how many times
// faster depthfuse is than libfreenect2: after the table on stdout in the console format, on
// stderr in the others (json, csv), so that their stdout stays what tools parse.
class RatioReporter : public benchmark::BenchmarkReporter {
 public:
  // The library owns the default display reporter (it is never freed).
  RatioReporter()
      : display_(benchmark::CreateDefaultDisplayReporter()),
        summary_(dynamic_cast<benchmark::ConsoleReporter*>(display_) ? stdout : stderr) {}

  bool ReportContext(const Context& context) override { return display_->ReportContext(context); }
  void ReportRuns(const std::vector<Run>& runs) override {
    for (const Run& run : runs) {
      // With --benchmark_repetitions, the median.
      const bool median = run.run_type == Run::RT_Aggregate && run.aggregate_name == "median";
      if (!(run.run_type == Run::RT_Iteration || median) || run.error_occurred) continue;
      std::string name = run.run_name.function_name;
      // All are registered in milliseconds.
      times_[name] = {run.GetAdjustedRealTime(), run.GetAdjustedCPUTime()};
    }
    display_->ReportRuns(runs);
  }
  void Finalize() override {
    display_->Finalize();
    std::fflush(stdout);
    ratio("BM_DecodeDepth/depthfuse", "BM_DecodeDepth/libfreenect2_cpu");
    ratio("BM_DecodeDepth/depthfuse_2threads", "BM_DecodeDepth/libfreenect2_cpu");
    ratio("BM_DecodeDepthNoFilters/depthfuse", "BM_DecodeDepthNoFilters/libfreenect2_cpu");
  }

 private:
  // Real time, and CPU time of the calling thread (the fair one on a loaded machine; it leaves
  // out the helper thread of depthfuse_2threads).
  void ratio(const std::string& ours, const std::string& theirs) {
    const auto a = times_.find(ours), b = times_.find(theirs);
    if (a == times_.end() || b == times_.end()) return;
    std::fprintf(summary_, "%s vs %s: real %.2f vs %.2f ms (%.1fx), CPU %.2f vs %.2f ms (%.1fx)\n",
                 ours.c_str(), theirs.c_str(), a->second.first, b->second.first,
                 b->second.first / a->second.first, a->second.second, b->second.second,
                 b->second.second / a->second.second);
  }
  benchmark::BenchmarkReporter* display_;
  FILE* summary_;
  std::map<std::string, std::pair<double, double>> times_;  // real, CPU (ms)
};

}  // namespace
}  // namespace depthfuse::kinect2

int main(int argc, char** argv) {
  using namespace depthfuse::kinect2;
  auto ms = [](benchmark::internal::Benchmark* b) { b->Unit(benchmark::kMillisecond)->UseRealTime(); };
  ms(benchmark::RegisterBenchmark("BM_DecodeDepth/depthfuse", decode_depthfuse, 1, true));
  ms(benchmark::RegisterBenchmark("BM_DecodeDepth/depthfuse_2threads", decode_depthfuse, 2, true));
#ifdef DF_HAVE_FREENECT2_REFERENCE
  ms(benchmark::RegisterBenchmark("BM_DecodeDepth/libfreenect2_cpu", decode_libfreenect2, true));
#endif
  ms(benchmark::RegisterBenchmark("BM_DecodeDepthNoFilters/depthfuse", decode_depthfuse, 1, false));
#ifdef DF_HAVE_FREENECT2_REFERENCE
  ms(benchmark::RegisterBenchmark("BM_DecodeDepthNoFilters/libfreenect2_cpu", decode_libfreenect2,
                                  false));
#endif
  ms(benchmark::RegisterBenchmark("BM_EncodePacket", encode));
  benchmark::Initialize(&argc, argv);
  if (benchmark::ReportUnrecognizedArguments(argc, argv)) return 1;
  RatioReporter reporter;  // after Initialize: it reads --benchmark_format
  benchmark::RunSpecifiedBenchmarks(&reporter);
  benchmark::Shutdown();
  return 0;
}
