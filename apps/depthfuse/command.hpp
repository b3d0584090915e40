// Subcommands of the `depthfuse` CLI register themselves; main.cpp only dispatches.
#pragma once

#include <string>
#include <vector>

namespace depthfuse::cli {

// argv[0] is the subcommand name. Returns the process exit code.
using CommandFn = int (*)(int argc, char** argv);

struct Command {
  const char* name;
  const char* usage;    // one line: "reconstruct <tum-folder> [...] -o cloud.ply"
  const char* summary;  // what it does
  CommandFn fn;
};

std::vector<Command>& registry();

struct Registrar {
  explicit Registrar(const Command& c) { registry().push_back(c); }
};

}  // namespace depthfuse::cli

#define DF_REGISTER_COMMAND(ident, name, usage, summary, fn) \
  static ::depthfuse::cli::Registrar ident##_registrar({name, usage, summary, fn})
