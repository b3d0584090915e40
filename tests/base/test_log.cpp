#include <gtest/gtest.h>

#include <string>

#include "depthfuse/base/clock.hpp"
#include "depthfuse/base/errno_text.hpp"
#include "depthfuse/base/log.hpp"

DF_LOG_CATEGORY(Alpha)
DF_LOG_CATEGORY(Beta)

namespace depthfuse::log {
namespace {

class LogTest : public ::testing::Test {
 protected:
  void SetUp() override {
    std::string error;
    ASSERT_TRUE(configure("info", &error)) << error;
    set_program_name("test-log");
  }
  void TearDown() override {
    std::string error;
    configure("info", &error);
  }
};

TEST_F(LogTest, WritesOneLinePerMessageWithTheProgramAndLevel) {
  ::testing::internal::CaptureStderr();
  DF_LOG(Alpha, Info) << "fused " << 3 << " frames";
  DF_LOG(Alpha, Warning) << "queue full";
  DF_LOG(Alpha, Error) << "cannot open x";
  EXPECT_EQ(::testing::internal::GetCapturedStderr(),
            "test-log: fused 3 frames\n"
            "test-log: warning: queue full\n"
            "test-log: cannot open x\n");
}

TEST_F(LogTest, HidesWhatIsBelowTheThresholdWithoutBuildingIt) {
  int built = 0;
  auto count = [&] { return ++built; };
  ::testing::internal::CaptureStderr();
  DF_LOG(Alpha, Debug) << count();
  EXPECT_EQ(::testing::internal::GetCapturedStderr(), "");
  EXPECT_EQ(built, 0);
}

TEST_F(LogTest, IsOneStatementInsideAnUnbracedIfElse) {
  ::testing::internal::CaptureStderr();
  for (bool first : {true, false}) {
    if (first)
      DF_LOG(Alpha, Info) << "then";
    else
      DF_LOG(Alpha, Info) << "else";
  }
  EXPECT_EQ(::testing::internal::GetCapturedStderr(), "test-log: then\ntest-log: else\n");
}

TEST_F(LogTest, PerCategoryThresholdsOverrideTheDefault) {
  std::string error;
  ASSERT_TRUE(configure("warning,Beta=debug", &error)) << error;
  ::testing::internal::CaptureStderr();
  DF_LOG(Alpha, Info) << "hidden";
  DF_LOG(Beta, Debug) << "shown";
  EXPECT_EQ(::testing::internal::GetCapturedStderr(), "test-log: debug: [Beta] shown\n");
}

TEST_F(LogTest, AMalformedSpecIsRefusedAndChangesNothing) {
  std::string error;
  EXPECT_FALSE(configure("loud", &error));
  EXPECT_NE(error.find("'loud'"), std::string::npos) << error;
  EXPECT_FALSE(configure("Beta=", &error));
  ::testing::internal::CaptureStderr();
  DF_LOG(Alpha, Info) << "still shown";
  EXPECT_EQ(::testing::internal::GetCapturedStderr(), "test-log: still shown\n");
}

TEST(Clock, SteadyNanosecondsDoNotGoBackAndWallTimeIsInMicroseconds) {
  const int64_t a = steady_ns(), b = steady_ns();
  EXPECT_LE(a, b);
  EXPECT_GT(now_utime(), int64_t{1'600'000'000} * 1'000'000);  // after 2020, in microseconds
  EXPECT_LT(now_utime(), int64_t{4'000'000'000} * 1'000'000);
}

TEST(ErrnoText, NamesTheError) { EXPECT_EQ(errno_text(ENOENT), "No such file or directory"); }

}  // namespace
}  // namespace depthfuse::log
