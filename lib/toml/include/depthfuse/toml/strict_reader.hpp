// The one strict TOML reader of depthfuse (the appliance's config file, the synthetic scenes'
// ground truth): reads a table, checking the type and the range of every value, and reports every
// problem of a file at once as "<origin>:<line>: <section.key>: <problem>". An unknown key is a
// problem. Only for libraries that already depend on toml++: this header includes it.
#pragma once

#include <cstdint>
#include <functional>
#include <optional>
#include <string>
#include <string_view>
#include <utility>
#include <vector>

#include <toml++/toml.h>

#include "depthfuse/status.hpp"
#include "depthfuse/toml/key_trace.hpp"

namespace depthfuse::strict_toml {

// Parses a document; a syntax error comes back as invalid_argument with the origin, line and
// column.
Result<toml::table> parse_document(const std::string& text, const std::string& origin);

// Every problem of one file, so that a user can fix them all in one go.
class Diagnostics {
 public:
  explicit Diagnostics(std::string origin) : origin_(std::move(origin)) {}

  // `key` is the full dotted key; `where` gives the line (line 0 = unknown, left out).
  void add(const toml::source_region& where, const std::string& key, const std::string& problem);
  bool ok() const { return messages_.empty(); }
  size_t count() const { return messages_.size(); }
  // ok, or invalid_argument with one problem per line, in the order of the file.
  Status status() const;
  const std::string& origin() const { return origin_; }

 private:
  std::string origin_;
  std::vector<std::pair<uint32_t, std::string>> messages_;  // (line, message)
};

// Allowed range of a number; a missing side is unbounded. Checked on ints and doubles alike.
// Infinities are refused unless `finite_only` is off (a half-plane's bounds).
struct Bounds {
  std::optional<double> min;
  bool min_exclusive = false;
  std::optional<double> max;
  bool max_exclusive = false;
  bool finite_only = true;

  // The rule text, e.g. "must be > 0", "must be in (0, 180]"; empty when unbounded.
  std::string rule() const;
  bool contains(double v) const;
};
inline Bounds positive() { return {0.0, true, std::nullopt, false}; }
inline Bounds non_negative() { return {0.0, false, std::nullopt, false}; }
inline Bounds at_least(double lo) { return {lo, false, std::nullopt, false}; }
inline Bounds any_number() { return {}; }
inline Bounds any_number_or_infinity() { return {std::nullopt, false, std::nullopt, false, false}; }
inline Bounds closed(double lo, double hi) { return {lo, false, hi, false}; }
inline Bounds open_closed(double lo, double hi) { return {lo, true, hi, false}; }

// A string rule: the problem with `s` ("must not be empty"), or nothing.
using StringRule = std::function<std::optional<std::string>(const std::string& s)>;
StringRule non_empty();
StringRule any_string();
StringRule one_of(std::vector<std::string> allowed);

// Formats a number for a message: -5, 0.0015, 1e-07.
std::string format_number(double v);

class TableReader {
 public:
  // `table` null means the section is absent: every read keeps its default. `path` is the dotted
  // prefix of the keys ("" for the document, "sensor", "device[0].sensor"). `trace` may be null.
  TableReader(const toml::table* table, std::string path, const toml::source_region& where,
              Diagnostics* diagnostics, std::vector<KeyTrace>* trace);

  // Each leaves *out unchanged when the key is absent or its value is rejected (and reported).
  // An integer is accepted where a float is expected, not the other way round.
  void read(std::string_view key, double* out, const Bounds& bounds);
  void read(std::string_view key, int* out, const Bounds& bounds);
  void read(std::string_view key, bool* out);
  void read(std::string_view key, std::string* out, const StringRule& rule);
  // A non-negative 64-bit integer (a seed): an integer, or beyond TOML's signed 64 bits a string
  // of decimal digits.
  void read(std::string_view key, uint64_t* out);
  // An array of exactly `count` numbers, each within `bounds`; out[0..count) is left unchanged
  // unless all of them pass.
  void read(std::string_view key, double* out, size_t count, const Bounds& bounds);
  // A key that must be present (e.g. a device's serial): reported at the table's line otherwise.
  void require(std::string_view key);

  // A sub-table: null when absent, or after reporting a value that is not a table.
  const toml::table* table(std::string_view key);
  // An array of tables ([[key]]): null when absent, or after reporting anything else.
  const toml::array* array_of_tables(std::string_view key);

  // Reports a rule that involves several keys, at `key`'s line (the table's when absent).
  void fail(std::string_view key, const std::string& problem);
  bool has(std::string_view key) const;
  std::string full_key(std::string_view key) const;
  const toml::source_region& where(std::string_view key) const;

  // Reports every key of the table that no read asked for. Call once, after all reads.
  void reject_unknown();
  // True while nothing read through this reader (or after its creation) was reported: rules that
  // combine keys only make sense on values that passed their own checks.
  bool clean() const { return diagnostics_->count() == errors_before_; }

  Diagnostics* diagnostics() const { return diagnostics_; }
  std::vector<KeyTrace>* trace() const { return trace_; }

 private:
  // The node of `key` (null if absent), remembering that `key` is known.
  const toml::node* lookup(std::string_view key);
  void record(std::string_view key, std::string value, bool from_file);
  void wrong_type(std::string_view key, const toml::node& node, const char* expected);
  // The number of `node` within `bounds`, or nothing after reporting why not.
  std::optional<double> number(std::string_view key, const toml::node& node,
                               const Bounds& bounds);

  const toml::table* table_;
  std::string path_;
  toml::source_region where_;
  Diagnostics* diagnostics_;
  std::vector<KeyTrace>* trace_;
  std::vector<std::string> known_;
  size_t errors_before_;
};

}  // namespace depthfuse::strict_toml
