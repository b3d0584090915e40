// The command line of every depthfuse program: "--name value" and "--name=value" options, flags
// that take no value, options whose value may be left out, and positional arguments. "-o FILE" is
// "--output FILE"; "-h" and "--help" are the flag "help". Numbers are parsed checked: garbage,
// NaN, infinities and values outside the option's range are errors that name the option.
#pragma once

#include <limits>
#include <map>
#include <string>
#include <vector>

namespace depthfuse::daemon {

// The values a number option accepts: from min to max, each end included unless it is open.
struct NumberRange {
  double min = -std::numeric_limits<double>::infinity();
  double max = std::numeric_limits<double>::infinity();
  bool min_open = false;
  bool max_open = false;

  bool contains(double v) const;
  // " > 0", " in [1, 10000]", " in (0, 1]"; empty when every finite number is allowed.
  std::string text() const;
};
// (0, inf): rates, durations, sizes.
NumberRange positive();
// [lo, hi].
NumberRange closed(double lo, double hi);
// (lo, hi].
NumberRange open_closed(double lo, double hi);

class Args {
 public:
  // Options named in `flags` take no value; those in `optional_values` take the next argument as
  // their value unless it starts with '-' (their value is "" then). Every other option takes one.
  Args(int argc, char** argv, const std::vector<std::string>& flags = {},
       const std::vector<std::string>& optional_values = {});

  bool ok() const { return error_.empty(); }
  const std::string& error() const { return error_; }
  bool has(const std::string& name) const { return values_.count(name) > 0; }
  std::string get(const std::string& name, const std::string& fallback = "") const;
  // An option given as a number: leaves *out unchanged when absent; false with the reason in
  // `error` when it is not a number in `range` ("--timeout expects a number > 0, got '-1'").
  bool get_int(const std::string& name, long* out, std::string* error,
               const NumberRange& range = {}) const;
  bool get_double(const std::string& name, double* out, std::string* error,
                  const NumberRange& range = {}) const;
  const std::vector<std::string>& positional() const { return positional_; }
  // The first option that was given but is not in `known` ("--colour", "-o"), else "". "help" is
  // always known.
  std::string unknown(const std::vector<std::string>& known) const;

 private:
  std::map<std::string, std::string> values_;
  std::vector<std::string> positional_;
  std::string error_;
};

}  // namespace depthfuse::daemon
