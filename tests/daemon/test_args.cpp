// daemon::Args: options, flags, optional values and positional arguments, and numbers that are
// checked against their range with an error that names the option.
#include <gtest/gtest.h>

#include <string>
#include <vector>

#include "depthfuse/daemon/args.hpp"

namespace depthfuse::daemon {
namespace {

// Args over a command line given as strings (argv[0] is the program).
Args parse(std::vector<std::string> words, const std::vector<std::string>& flags = {},
           const std::vector<std::string>& optional_values = {}) {
  words.insert(words.begin(), "prog");
  std::vector<char*> argv;
  for (auto& w : words) argv.push_back(w.data());
  return Args(static_cast<int>(argv.size()), argv.data(), flags, optional_values);
}

TEST(DaemonArgs, OptionsFlagsAndPositionalArguments) {
  const Args a = parse({"start", "--target", "fusion", "--no-wait", "--lcm=udpm://x", "-o", "out.ply",
                        "name"},
                       {"no-wait"});
  ASSERT_TRUE(a.ok()) << a.error();
  EXPECT_EQ(a.get("target"), "fusion");
  EXPECT_TRUE(a.has("no-wait"));
  EXPECT_EQ(a.get("lcm"), "udpm://x");
  EXPECT_EQ(a.get("output"), "out.ply");
  EXPECT_EQ(a.get("absent", "fallback"), "fallback");
  EXPECT_EQ(a.positional(), (std::vector<std::string>{"start", "name"}));
  EXPECT_EQ(a.unknown({"target", "no-wait", "lcm"}), "-o");
  EXPECT_EQ(a.unknown({"target", "no-wait", "lcm", "output"}), "");
}

TEST(DaemonArgs, AnOptionWithoutItsValueIsAnError) {
  const Args a = parse({"--timeout"});
  EXPECT_FALSE(a.ok());
  EXPECT_NE(a.error().find("--timeout"), std::string::npos) << a.error();
}

TEST(DaemonArgs, AnOptionalValueIsTakenUnlessTheNextWordIsAnOption) {
  const Args named = parse({"--autostart", "scan1", "--queue", "3"}, {}, {"autostart"});
  ASSERT_TRUE(named.ok()) << named.error();
  EXPECT_EQ(named.get("autostart"), "scan1");
  const Args bare = parse({"--autostart", "--queue", "3"}, {}, {"autostart"});
  ASSERT_TRUE(bare.ok()) << bare.error();
  EXPECT_TRUE(bare.has("autostart"));
  EXPECT_EQ(bare.get("autostart"), "");
  EXPECT_EQ(bare.get("queue"), "3");
}

TEST(DaemonArgs, HelpIsAlwaysKnown) {
  for (const char* word : {"-h", "--help"}) {
    const Args a = parse({word});
    EXPECT_TRUE(a.has("help")) << word;
    EXPECT_EQ(a.unknown({}), "") << word;
  }
}

TEST(DaemonArgs, NumbersAreCheckedAndAnAbsentOptionKeepsItsDefault) {
  const Args a = parse({"--timeout", "2.5", "--queue", "12"});
  double timeout_s = 3.0, absent = 7.0;
  long queue = 4;
  std::string error;
  EXPECT_TRUE(a.get_double("timeout", &timeout_s, &error, positive())) << error;
  EXPECT_EQ(timeout_s, 2.5);
  EXPECT_TRUE(a.get_int("queue", &queue, &error, closed(1, 10000))) << error;
  EXPECT_EQ(queue, 12);
  EXPECT_TRUE(a.get_double("rate", &absent, &error));
  EXPECT_EQ(absent, 7.0);
}

TEST(DaemonArgs, GarbageAndOutOfRangeNumbersNameTheOptionAndLeaveTheValue) {
  struct Case {
    const char* value;
    NumberRange range;
    const char* says;
  };
  const Case cases[] = {
      {"abc", positive(), "--timeout expects a number > 0, got 'abc'"},
      {"3s", positive(), "--timeout expects a number > 0, got '3s'"},
      {"", positive(), "--timeout expects a number > 0, got ''"},
      {"nan", {}, "--timeout expects a number, got 'nan'"},
      {"inf", {}, "--timeout expects a number, got 'inf'"},
      {"0", positive(), "--timeout expects a number > 0, got '0'"},
      {"-1", positive(), "--timeout expects a number > 0, got '-1'"},
      {"2", open_closed(0, 1), "--timeout expects a number in (0, 1], got '2'"},
  };
  for (const Case& c : cases) {
    SCOPED_TRACE(c.value);
    const Args a = parse({std::string("--timeout=") + c.value});
    double timeout_s = 3.0;
    std::string error;
    EXPECT_FALSE(a.get_double("timeout", &timeout_s, &error, c.range));
    EXPECT_EQ(error, c.says);
    EXPECT_EQ(timeout_s, 3.0);
  }
  const Args q = parse({"--queue", "1.5"});
  long queue = 4;
  std::string error;
  EXPECT_FALSE(q.get_int("queue", &queue, &error, closed(1, 10000)));
  EXPECT_EQ(error, "--queue expects an integer in [1, 10000], got '1.5'");
  EXPECT_EQ(queue, 4);
  const Args big = parse({"--queue", "99999999999999999999999"});
  EXPECT_FALSE(big.get_int("queue", &queue, &error));
  EXPECT_EQ(queue, 4);
}

}  // namespace
}  // namespace depthfuse::daemon
