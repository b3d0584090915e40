// Small helpers shared by the CLI's subcommands: option parsing, progress, config loading.
#pragma once

#include <cstdio>
#include <map>
#include <optional>
#include <string>
#include <vector>

#include "depthfuse/app_config.hpp"
#include "depthfuse/pipeline.hpp"

namespace depthfuse::cli {

// "--name value" options and positional arguments. Flags listed in `flags` take no value.
class Args {
 public:
  Args(int argc, char** argv, const std::vector<std::string>& flags = {});
  bool ok() const { return error_.empty(); }
  const std::string& error() const { return error_; }
  bool has(const std::string& name) const { return values_.count(name) > 0; }
  std::string get(const std::string& name, const std::string& fallback = "") const;
  // Number parsing with a clear error into `error` (and false) on garbage.
  bool get_int(const std::string& name, long* out, std::string* error) const;
  bool get_double(const std::string& name, double* out, std::string* error) const;
  const std::vector<std::string>& positional() const { return positional_; }
  // Options that were given but are not in `known`: each is an error.
  std::string unknown(const std::vector<std::string>& known) const;

 private:
  std::map<std::string, std::string> values_;
  std::vector<std::string> positional_;
  std::string error_;
};

// Loads --config if given (else defaults); prints the error and returns nullopt on failure.
std::optional<AppConfig> load_config_or_report(const Args& args, const char* command);

// A bar on a terminal, a plain line every 10 % otherwise (logs, CI).
class Progress {
 public:
  explicit Progress(FILE* out = stderr);
  void operator()(const std::string& stage, size_t done, size_t total);
  ProgressFn fn() { return [this](const std::string& s, size_t d, size_t t) { (*this)(s, d, t); }; }

 private:
  FILE* out_;
  bool tty_;
  std::string stage_;
  int last_decile_ = -1;
};

// One line of a batch run's report: "    1: points ..., registered 18/20 frames, ...". Iteration 0 is
// the first fusion, without registration.
std::string describe_iteration(const BatchIterationReport& it, size_t frames);

int fail(const char* command, const std::string& message);  // prints "depthfuse <command>: ..." → 1

}  // namespace depthfuse::cli
