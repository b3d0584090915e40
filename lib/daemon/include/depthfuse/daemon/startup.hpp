// How every program of the appliance starts, written once: the log (the program's name as the
// prefix of its lines, --log-level), the command line (--help, unknown options and stray arguments
// are errors), the config (--config, else the built-in defaults) and LCM (--lcm, else the config's
// lcm.url; the transport's warnings are logged). The capture, fusion and monitor daemons and every
// subcommand of the CLI are this plus their own options:
//
//   daemon::Startup startup({"depthfuse-monitor", kUsage, {"stale-after", "rate"}}, argc, argv);
//   if (auto code = startup.exit_code()) return *code;
//   ... startup.args(), startup.config() ...
//   auto lcm = startup.open_lcm();
//   if (!lcm) return 1;
//
// and its main runs inside run_main(), which turns an exception that escaped into one line on
// stderr and exit code 1.
#pragma once

#include <functional>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include "depthfuse/app_config.hpp"
#include "depthfuse/daemon/args.hpp"
#include "depthfuse/lcm/transport.hpp"

namespace depthfuse::daemon {

// A program's own part of the command line; --log-level and --help are common to all, --config
// to those that read the appliance's config file, --lcm and --key-file to those on the bus.
struct Program {
  std::string name;   // "depthfuse-capture", "depthfuse scan": the prefix of its log lines
  std::string usage;  // the --help text, without the common options' lines
  std::vector<std::string> options;          // its options that take a value
  std::vector<std::string> flags;            // its options that take none
  std::vector<std::string> optional_values;  // its options whose value may be left out
  size_t max_positional = 0;
  // An offline command that reads no config file (synth, eval, export, inspect) or uses no bus
  // (none of the offline ones) refuses those options: ignored, they would look as if they counted.
  bool reads_config = true;
  bool uses_lcm = true;
};

// The config --config names (after its checks), else the defaults.
Result<AppConfig> load_config(const Args& args);

class Startup {
 public:
  // Names the log, parses argv[1..], applies --log-level and loads the config. --lcm, when given
  // (and not empty), replaces the config's lcm.url.
  Startup(Program program, int argc, char** argv);

  // Set when the program ends here: 0 after --help (the usage on stdout), 2 after a bad argument
  // or config (said on stderr; for an argument, followed by the usage).
  std::optional<int> exit_code() const { return exit_code_; }

  const Args& args() const { return args_; }
  AppConfig& config() { return config_; }
  const AppConfig& config() const { return config_; }

  // A problem the program found in its own options: says it and the usage on stderr; returns 2.
  int usage_error(const std::string& problem) const;

  // Opens LCM at config().lcm.url, logging the transport's warnings. Null, after logging why
  // (route, URL syntax, ...), when it cannot.
  std::unique_ptr<lcm::LcmTransport> open_lcm() const;

  // The rig key at config().lcm.key_file: none when the setting is empty (the explicit choice of
  // an open bus), an error naming the file and the fix when it is missing or unusable (a broken
  // rig, not an open one). open_lcm() uses it; so does the monitor, which checks the page's
  // commands with it.
  Result<std::optional<lcm::RigKey>> rig_key() const;

 private:
  Program program_;
  Args args_;
  AppConfig config_;
  std::optional<int> exit_code_;
};

// Runs the program proper. An exception that escapes it is logged as one line ("<program>:
// unexpected error: ...") and gives exit code 1, where it would otherwise abort the process.
int run_main(const std::function<int()>& body);

}  // namespace depthfuse::daemon
