// daemon::Startup: what every program does before its own work (--help, bad arguments, --config,
// --lcm, --log-level), and run_main's catch-all.
#include <gtest/gtest.h>

#include <stdexcept>
#include <string>
#include <vector>

#include "depthfuse/daemon/startup.hpp"

namespace depthfuse::daemon {
namespace {

const Program kProgram{"test-startup", "usage: test-startup [--rate HZ] [--loop] [ARG]\n",
                       {"rate"}, {"loop"}, {}, 1};

// An offline program: no config file, no bus.
const Program kOffline{"test-offline", "usage: test-offline ARG\n", {}, {}, {}, 1, false, false};

struct Started {
  std::optional<int> exit_code;
  std::string out, err;
  std::string lcm_url;
};

Started start(std::vector<std::string> words, const Program& program = kProgram) {
  words.insert(words.begin(), program.name);
  std::vector<char*> argv;
  for (auto& w : words) argv.push_back(w.data());
  ::testing::internal::CaptureStdout();
  ::testing::internal::CaptureStderr();
  Startup startup(program, static_cast<int>(argv.size()), argv.data());
  Started s;
  s.exit_code = startup.exit_code();
  s.out = ::testing::internal::GetCapturedStdout();
  s.err = ::testing::internal::GetCapturedStderr();
  s.lcm_url = startup.config().lcm.url;
  return s;
}

TEST(DaemonStartup, HelpPrintsTheUsageAndTheCommonOptionsOnStdout) {
  const Started s = start({"--help"});
  ASSERT_TRUE(s.exit_code.has_value());
  EXPECT_EQ(*s.exit_code, 0);
  EXPECT_EQ(s.out.rfind("usage: test-startup", 0), 0u) << s.out;
  EXPECT_NE(s.out.find("--log-level"), std::string::npos) << s.out;
  EXPECT_EQ(s.err, "");
}

TEST(DaemonStartup, BadArgumentsAreSaidWithTheUsageAndExitTwo) {
  struct Case {
    std::vector<std::string> words;
    const char* says;
  };
  const std::vector<Case> cases = {
      {{"--colour", "red"}, "test-startup: unknown option --colour\n"},
      {{"one", "two"}, "test-startup: unexpected argument 'two'\n"},
      {{"--rate"}, "test-startup: option --rate needs a value\n"},
      {{"--log-level", "loud"}, "test-startup: --log-level: "},
      {{"--lcm", ""}, "test-startup: --lcm needs a URL"},
  };
  for (const Case& c : cases) {
    SCOPED_TRACE(c.words[0]);
    const Started s = start(c.words);
    ASSERT_TRUE(s.exit_code.has_value());
    EXPECT_EQ(*s.exit_code, 2);
    EXPECT_EQ(s.err.rfind(c.says, 0), 0u) << s.err;
    EXPECT_NE(s.err.find("usage: test-startup"), std::string::npos) << s.err;
    EXPECT_EQ(s.out, "");
  }
}

TEST(DaemonStartup, AProgramWithoutConfigOrBusRefusesTheirOptionsAndTakesTheLogLevel) {
  const Started help = start({"--help"}, kOffline);
  EXPECT_EQ(help.exit_code, 0);
  EXPECT_NE(help.out.find("--log-level"), std::string::npos) << help.out;
  EXPECT_EQ(help.out.find("--key-file"), std::string::npos) << help.out;
  for (const char* option : {"--config", "--lcm", "--key-file"}) {
    SCOPED_TRACE(option);
    const Started s = start({option, "x", "arg"}, kOffline);
    EXPECT_EQ(s.exit_code, 2);
    EXPECT_EQ(s.err.rfind("test-offline: unknown option " + std::string(option) + "\n", 0), 0u)
        << s.err;
  }
  const Started ok = start({"--log-level", "info", "arg"}, kOffline);
  EXPECT_FALSE(ok.exit_code.has_value()) << ok.err;
  const Started bad = start({"--log-level", "loud", "arg"}, kOffline);
  EXPECT_EQ(bad.exit_code, 2);
  EXPECT_EQ(bad.err.rfind("test-offline: --log-level: ", 0), 0u) << bad.err;
}

TEST(DaemonStartup, AConfigThatDoesNotLoadExitsTwo) {
  const Started s = start({"--config", "/nonexistent/depthfuse.toml"});
  ASSERT_TRUE(s.exit_code.has_value());
  EXPECT_EQ(*s.exit_code, 2);
  EXPECT_NE(s.err.find("/nonexistent/depthfuse.toml"), std::string::npos) << s.err;
}

TEST(DaemonStartup, GoodArgumentsGoOnWithTheConfigAndLcmOverridesItsUrl) {
  const Started defaults = start({"--rate", "5", "--loop", "arg"});
  EXPECT_FALSE(defaults.exit_code.has_value()) << defaults.err;
  EXPECT_EQ(defaults.lcm_url, AppConfig{}.lcm.url);
  const Started given = start({"--lcm", "udpm://239.255.76.67:7667?ttl=0"});
  EXPECT_FALSE(given.exit_code.has_value()) << given.err;
  EXPECT_EQ(given.lcm_url, "udpm://239.255.76.67:7667?ttl=0");
}

TEST(DaemonStartup, AnExceptionThatEscapesMainIsOneLineAndExitOne) {
  ::testing::internal::CaptureStderr();
  const int code = run_main([]() -> int { throw std::runtime_error("disk on fire"); });
  const std::string err = ::testing::internal::GetCapturedStderr();
  EXPECT_EQ(code, 1);
  EXPECT_NE(err.find("unexpected error: disk on fire"), std::string::npos) << err;
  EXPECT_EQ(run_main([] { return 7; }), 7);
}

}  // namespace
}  // namespace depthfuse::daemon
