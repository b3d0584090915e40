// depthfuse: the offline and operator command line. Each subcommand lives in its own cmd_*.cpp.
#include <algorithm>
#include <cstdio>
#include <cstring>
#include <string>

#include "command.hpp"
#include "depthfuse/base/log.hpp"
#include "depthfuse/daemon/startup.hpp"

DF_LOG_CATEGORY(Cli)

namespace depthfuse::cli {
std::vector<Command>& registry() {
  static std::vector<Command> commands;
  return commands;
}
}  // namespace depthfuse::cli

static void print_usage(FILE* out) {
  auto cmds = depthfuse::cli::registry();
  std::sort(cmds.begin(), cmds.end(),
            [](const auto& a, const auto& b) { return std::strcmp(a.name, b.name) < 0; });
  std::fprintf(out, "usage: depthfuse <command> [options]\n\ncommands:\n");
  for (const auto& c : cmds) std::fprintf(out, "  %-10s %s\n", c.name, c.summary);
  std::fprintf(out, "\n'depthfuse <command> --help' shows a command's options.\n");
}

int main(int argc, char** argv) {
  depthfuse::log::set_program_name("depthfuse");
  if (argc < 2 || !std::strcmp(argv[1], "--help") || !std::strcmp(argv[1], "-h") ||
      !std::strcmp(argv[1], "help")) {
    print_usage(argc < 2 ? stderr : stdout);
    return argc < 2 ? 2 : 0;
  }
  for (const auto& c : depthfuse::cli::registry()) {
    if (std::strcmp(c.name, argv[1])) continue;
    // The command's messages read "depthfuse <command>: ...".
    depthfuse::log::set_program_name(std::string("depthfuse ") + c.name);
    return depthfuse::daemon::run_main([&] { return c.fn(argc - 1, argv + 1); });
  }
  DF_LOG(Cli, Error) << "unknown command '" << argv[1] << "'";
  print_usage(stderr);
  return 2;
}
