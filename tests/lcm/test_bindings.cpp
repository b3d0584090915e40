// The Python and Java bindings generated at build time speak the same protocol as C++.
#include <gtest/gtest.h>

#include <cstdio>
#include <filesystem>
#include <sstream>

#include "depthfuse/command_t.hpp"
#include "depthfuse/heartbeat_t.hpp"
#include "depthfuse/lcm/codec.hpp"
#include "lcm_test_util.hpp"

namespace depthfuse {
namespace {

std::vector<uint8_t> from_hex(const std::string& hex) {
  std::vector<uint8_t> out;
  for (size_t i = 0; i + 1 < hex.size(); i += 2) out.push_back(static_cast<uint8_t>(std::stoi(hex.substr(i, 2), nullptr, 16)));
  return out;
}

TEST(Bindings, PythonEncodesWhatCppDecodes) {
  const std::string dir = testing::temp_dir("bindings");
  std::string out;
  const int rc = testing::run_command({DEPTHFUSE_PYTHON3, DEPTHFUSE_TEST_DIR "/python_encode.py",
                                       DEPTHFUSE_PYTHON_DIR},
                                      dir + "/python.log", &out);
  ASSERT_EQ(rc, 0) << out;
  std::istringstream lines(out);
  std::string hb_hex, cmd_hex;
  ASSERT_TRUE(std::getline(lines, hb_hex) && std::getline(lines, cmd_hex)) << out;

  const auto hb_bytes = from_hex(hb_hex);
  depthfuse::heartbeat_t hb;
  ASSERT_EQ(lcm::decode_message(hb_bytes.data(), hb_bytes.size(), &hb), lcm::DecodeResult::kOk);
  EXPECT_EQ(hb.name, "python");
  EXPECT_EQ(hb.host, "remote");
  EXPECT_EQ(hb.pid, 4242);
  EXPECT_EQ(hb.state, int8_t{depthfuse::heartbeat_t::STATE_RUNNING});
  EXPECT_EQ(hb.point_count, 987654321);
  EXPECT_EQ(hb.last_error, "none \xc3\xa9");
  ASSERT_EQ(hb.counters.size(), 1u);
  EXPECT_EQ(hb.counters[0].key, "answer");
  EXPECT_EQ(hb.counters[0].value, 42.5);

  const auto cmd_bytes = from_hex(cmd_hex);
  depthfuse::command_t cmd;
  ASSERT_EQ(lcm::decode_message(cmd_bytes.data(), cmd_bytes.size(), &cmd), lcm::DecodeResult::kOk);
  EXPECT_EQ(cmd.command_id, 77);
  EXPECT_EQ(cmd.action, int8_t{depthfuse::command_t::ACTION_STOP});
  EXPECT_EQ(cmd.target, "fusion");
}

TEST(Bindings, JavaJarHasEveryType) {
  const std::string jar = DEPTHFUSE_LCM_JAR;
  if (jar.empty()) GTEST_SKIP() << "no JDK or lcm.jar at build time: Java bindings not built";
  ASSERT_TRUE(std::filesystem::exists(jar)) << jar;
  std::string out;
  const int rc = testing::run_command({"/usr/bin/env", "jar", "tf", jar},
                                      testing::temp_dir("jar") + "/jar.log", &out);
  ASSERT_EQ(rc, 0) << out;
  for (const char* type : {"depth_frame_t", "color_frame_t", "pose_t", "heartbeat_t", "status_t",
                           "daemon_status_t", "command_t", "intrinsics_t", "key_value_t"})
    EXPECT_NE(out.find(std::string("depthfuse/") + type + ".class"), std::string::npos) << type;
}

}  // namespace
}  // namespace depthfuse
