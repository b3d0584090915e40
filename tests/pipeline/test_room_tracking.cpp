// The first re-registration round tracks every frame against the cloud fused from its perturbed
// poses, a cloud as blurred as those poses are wrong. On the synthetic room the cameras look across
// the room: a model that keeps only the front layers of the blurred walls pulls every camera back
// along its view, and nothing pulls it forward again (registration.tracking_model_band_m in
// config/depthfuse.toml). The cameras' mean offset along their own view measures it.
#include <gtest/gtest.h>

#include <cmath>
#include <cstdio>

#include "depthfuse/pipeline.hpp"
#include "depthfuse/synthetic/synthetic_sequence.hpp"
#include "depthfuse/trajectory.hpp"
#include "pipeline_test_util.hpp"

using namespace depthfuse;

namespace {

class RoomTracking : public ::testing::Test {
 protected:
  static void SetUpTestSuite() {
    // The evaluation's room (tools/eval/run_synthetic.sh): 40 frames, 2 cm / 1 degree.
    auto seq = synthetic::SyntheticSequence::create(
        test::perturbed_scan(synthetic::SceneKind::kRoom, 40, 1));
    ASSERT_TRUE(seq.is_ok()) << seq.status().to_string();
    scan_ = test::RenderedScan::of(*seq);
  }
  static void TearDownTestSuite() { scan_ = {}; }

  // The mean, over the frames, of each camera's offset from the truth along its true viewing
  // direction after one round of re-registration (m; negative: behind), in the truth's frame.
  static double mean_offset_along_view_m(double tracking_band_m) {
    ReconstructionConfig rc;
    rc.pipeline.method = Method::kFull;
    rc.pipeline.outer_iterations = 1;
    rc.registration.tracking_model_band_m = tracking_band_m;
    auto r = reconstruct_batch(scan_.frames, scan_.perturbed, rc);
    EXPECT_TRUE(r.is_ok()) << r.status().to_string();
    if (!r.is_ok()) return 0.0;
    auto ate = absolute_trajectory_error(r->T_world_cam, scan_.truth);
    EXPECT_TRUE(ate.is_ok());
    if (!ate.is_ok()) return 0.0;
    double sum = 0.0;
    for (size_t i = 0; i < scan_.truth.size(); ++i) {
      const Eigen::Vector3d offset =
          ate->T_truth_estimate * r->T_world_cam[i].translation() - scan_.truth[i].translation();
      sum += offset.dot(scan_.truth[i].linear().col(2));
    }
    const double mean = sum / static_cast<double>(scan_.truth.size());
    std::printf("tracking band %.2f m: mean offset along the view %.1f mm, ATE %.1f mm\n",
                tracking_band_m, mean * 1e3, ate->rmse_m * 1e3);
    return mean;
  }

  static test::RenderedScan scan_;
};

test::RenderedScan RoomTracking::scan_;

TEST_F(RoomTracking, TheFirstRoundLeavesTheCamerasWhereTheyLook) {
  // The shipped band: within a few millimetres (measured: -0.2 mm).
  const double shipped_m = ReconstructionConfig().registration.tracking_model_band_m;
  EXPECT_LT(std::abs(mean_offset_along_view_m(shipped_m)), 0.004);
  // The refine band, 5 cm, on the same data: every camera pulled back (measured: -11 mm). This is
  // what the check above guards against.
  EXPECT_LT(mean_offset_along_view_m(0.05), -0.006);
}

}  // namespace
