#include "depthfuse/toml/strict_reader.hpp"

#include <algorithm>
#include <charconv>
#include <climits>
#include <cmath>
#include <cstdio>
#include <utility>

namespace depthfuse::strict_toml {
namespace {

const char* type_name(toml::node_type t) {
  switch (t) {
    case toml::node_type::table: return "a table";
    case toml::node_type::array: return "an array";
    case toml::node_type::string: return "a string";
    case toml::node_type::integer: return "an integer";
    case toml::node_type::floating_point: return "a floating-point number";
    case toml::node_type::boolean: return "a boolean";
    case toml::node_type::date: return "a date";
    case toml::node_type::time: return "a time";
    case toml::node_type::date_time: return "a date-time";
    case toml::node_type::none: break;
  }
  return "nothing";
}

// Exact text of a double (round-trips), for the key trace.
std::string exact(double v) {
  char buf[40];
  std::snprintf(buf, sizeof buf, "%.17g", v);
  return buf;
}

std::string quoted(const std::string& s) { return "\"" + s + "\""; }

size_t edit_distance(std::string_view a, std::string_view b) {
  std::vector<size_t> row(b.size() + 1);
  for (size_t j = 0; j <= b.size(); ++j) row[j] = j;
  for (size_t i = 1; i <= a.size(); ++i) {
    size_t diagonal = row[0];
    row[0] = i;
    for (size_t j = 1; j <= b.size(); ++j) {
      const size_t above = row[j];
      row[j] = std::min({row[j] + 1, row[j - 1] + 1, diagonal + (a[i - 1] == b[j - 1] ? 0 : 1)});
      diagonal = above;
    }
  }
  return row[b.size()];
}

Status syntax_error(const std::string& origin, const toml::source_region& where,
                    std::string_view description) {
  std::string m = origin;
  if (where.begin.line > 0) m += ":" + std::to_string(where.begin.line);
  m += ": TOML syntax error";
  if (where.begin.column > 0) m += " at column " + std::to_string(where.begin.column);
  m += ": " + std::string(description);
  return invalid_argument(m);
}

}  // namespace

Result<toml::table> parse_document(const std::string& text, const std::string& origin) {
#if TOML_EXCEPTIONS
  try {
    return toml::parse(text, origin);
  } catch (const toml::parse_error& e) {
    return syntax_error(origin, e.source(), e.description());
  }
#else
  toml::parse_result parsed = toml::parse(text, origin);
  if (!parsed) return syntax_error(origin, parsed.error().source(), parsed.error().description());
  return std::move(parsed).table();
#endif
}

void Diagnostics::add(const toml::source_region& where, const std::string& key,
                      const std::string& problem) {
  std::string m = origin_;
  if (where.begin.line > 0) m += ":" + std::to_string(where.begin.line);
  m += ": " + key + ": " + problem;
  messages_.emplace_back(where.begin.line, std::move(m));
}

Status Diagnostics::status() const {
  if (messages_.empty()) return Status::ok();
  auto sorted = messages_;
  std::stable_sort(sorted.begin(), sorted.end(),
                   [](const auto& a, const auto& b) { return a.first < b.first; });
  std::string all;
  for (const auto& m : sorted) {
    if (!all.empty()) all += '\n';
    all += m.second;
  }
  return invalid_argument(all);
}

std::string format_number(double v) {
  char buf[40];
  std::snprintf(buf, sizeof buf, "%.10g", v);
  return buf;
}

std::string Bounds::rule() const {
  if (min && max) {
    return "must be in " + std::string(min_exclusive ? "(" : "[") + format_number(*min) + ", " +
           format_number(*max) + (max_exclusive ? ")" : "]");
  }
  if (min) return std::string("must be ") + (min_exclusive ? "> " : ">= ") + format_number(*min);
  if (max) return std::string("must be ") + (max_exclusive ? "< " : "<= ") + format_number(*max);
  return {};
}

bool Bounds::contains(double v) const {
  if (finite_only && !std::isfinite(v)) return false;
  if (min && (min_exclusive ? !(v > *min) : !(v >= *min))) return false;
  if (max && (max_exclusive ? !(v < *max) : !(v <= *max))) return false;
  return true;
}

StringRule non_empty() {
  return [](const std::string& s) -> std::optional<std::string> {
    if (s.empty()) return std::string("must not be empty");
    return std::nullopt;
  };
}

StringRule any_string() {
  return [](const std::string&) -> std::optional<std::string> { return std::nullopt; };
}

StringRule one_of(std::vector<std::string> allowed) {
  return [allowed = std::move(allowed)](const std::string& s) -> std::optional<std::string> {
    if (std::find(allowed.begin(), allowed.end(), s) != allowed.end()) return std::nullopt;
    std::string list;
    for (const auto& a : allowed) list += (list.empty() ? "" : ", ") + quoted(a);
    return "must be one of " + list + ", got " + quoted(s);
  };
}

TableReader::TableReader(const toml::table* table, std::string path,
                         const toml::source_region& where, Diagnostics* diagnostics,
                         std::vector<KeyTrace>* trace)
    : table_(table), path_(std::move(path)), where_(where), diagnostics_(diagnostics),
      trace_(trace), errors_before_(diagnostics->count()) {}

std::string TableReader::full_key(std::string_view key) const {
  if (path_.empty()) return std::string(key);
  return path_ + "." + std::string(key);
}

bool TableReader::has(std::string_view key) const {
  return table_ != nullptr && table_->get(key) != nullptr;
}

const toml::source_region& TableReader::where(std::string_view key) const {
  if (table_ != nullptr) {
    if (const toml::node* n = table_->get(key)) return n->source();
  }
  return where_;
}

const toml::node* TableReader::lookup(std::string_view key) {
  if (std::find(known_.begin(), known_.end(), key) == known_.end()) known_.emplace_back(key);
  return table_ != nullptr ? table_->get(key) : nullptr;
}

void TableReader::record(std::string_view key, std::string value, bool from_file) {
  if (trace_ != nullptr) trace_->push_back({full_key(key), std::move(value), from_file});
}

void TableReader::wrong_type(std::string_view key, const toml::node& node, const char* expected) {
  diagnostics_->add(node.source(), full_key(key),
                    std::string("expected ") + expected + ", got " + type_name(node.type()));
}

void TableReader::fail(std::string_view key, const std::string& problem) {
  diagnostics_->add(where(key), full_key(key), problem);
}

std::optional<double> TableReader::number(std::string_view key, const toml::node& node,
                                          const Bounds& bounds) {
  double v = 0.0;
  if (const auto* f = node.as_floating_point()) {
    v = f->get();
  } else if (const auto* i = node.as_integer()) {
    v = static_cast<double>(i->get());
  } else {
    wrong_type(key, node, "a number");
    return std::nullopt;
  }
  if (bounds.finite_only && !std::isfinite(v)) {
    diagnostics_->add(node.source(), full_key(key), "must be a finite number, got " + format_number(v));
    return std::nullopt;
  }
  if (!bounds.contains(v)) {
    diagnostics_->add(node.source(), full_key(key), bounds.rule() + ", got " + format_number(v));
    return std::nullopt;
  }
  return v;
}

void TableReader::read(std::string_view key, double* out, const Bounds& bounds) {
  const toml::node* node = lookup(key);
  if (node != nullptr) {
    const std::optional<double> v = number(key, *node, bounds);
    if (!v) return;
    *out = *v;
  }
  record(key, exact(*out), node != nullptr);
}

void TableReader::read(std::string_view key, double* out, size_t count, const Bounds& bounds) {
  const toml::node* node = lookup(key);
  if (node != nullptr) {
    const toml::array* a = node->as_array();
    const std::string expected = "an array of " + std::to_string(count) + " numbers";
    if (a == nullptr) {
      wrong_type(key, *node, expected.c_str());
      return;
    }
    if (a->size() != count) {
      diagnostics_->add(node->source(), full_key(key),
                        "expected " + expected + ", got " + std::to_string(a->size()) + " values");
      return;
    }
    std::vector<double> values(count);
    for (size_t k = 0; k < count; ++k) {
      const std::string element = std::string(key) + "[" + std::to_string(k) + "]";
      const std::optional<double> v = number(element, *a->get(k), bounds);
      if (!v) return;
      values[k] = *v;
    }
    std::copy(values.begin(), values.end(), out);
  }
  std::string text = "[";
  for (size_t k = 0; k < count; ++k) text += (k ? ", " : "") + exact(out[k]);
  record(key, text + "]", node != nullptr);
}

void TableReader::read(std::string_view key, uint64_t* out) {
  const toml::node* node = lookup(key);
  if (node != nullptr) {
    const char* rule = "must be a non-negative integer (a string of digits beyond 2^63 - 1)";
    uint64_t v = 0;
    if (const auto* i = node->as_integer()) {
      if (i->get() < 0) {
        diagnostics_->add(node->source(), full_key(key),
                          std::string(rule) + ", got " + std::to_string(i->get()));
        return;
      }
      v = static_cast<uint64_t>(i->get());
    } else if (const auto* s = node->as_string()) {
      const std::string& text = s->get();
      const auto [end, ec] = std::from_chars(text.data(), text.data() + text.size(), v);
      if (text.empty() || ec != std::errc() || end != text.data() + text.size()) {
        diagnostics_->add(node->source(), full_key(key), std::string(rule) + ", got " + quoted(text));
        return;
      }
    } else {
      wrong_type(key, *node, "a non-negative integer");
      return;
    }
    *out = v;
  }
  record(key, std::to_string(*out), node != nullptr);
}

void TableReader::read(std::string_view key, int* out, const Bounds& bounds) {
  const toml::node* node = lookup(key);
  if (node != nullptr) {
    const auto* i = node->as_integer();
    if (i == nullptr) {
      wrong_type(key, *node, "an integer");
      return;
    }
    const int64_t v = i->get();
    if (v < INT_MIN || v > INT_MAX) {
      diagnostics_->add(node->source(), full_key(key), "out of range, got " + std::to_string(v));
      return;
    }
    if (!bounds.contains(static_cast<double>(v))) {
      diagnostics_->add(node->source(), full_key(key), bounds.rule() + ", got " + std::to_string(v));
      return;
    }
    *out = static_cast<int>(v);
  }
  record(key, std::to_string(*out), node != nullptr);
}

void TableReader::read(std::string_view key, bool* out) {
  const toml::node* node = lookup(key);
  if (node != nullptr) {
    const auto* b = node->as_boolean();
    if (b == nullptr) {
      wrong_type(key, *node, "a boolean (true or false)");
      return;
    }
    *out = b->get();
  }
  record(key, *out ? "true" : "false", node != nullptr);
}

void TableReader::read(std::string_view key, std::string* out, const StringRule& rule) {
  const toml::node* node = lookup(key);
  if (node != nullptr) {
    const auto* s = node->as_string();
    if (s == nullptr) {
      wrong_type(key, *node, "a string");
      return;
    }
    if (rule) {
      if (auto problem = rule(s->get())) {
        diagnostics_->add(node->source(), full_key(key), *problem);
        return;
      }
    }
    *out = s->get();
  }
  record(key, quoted(*out), node != nullptr);
}

void TableReader::require(std::string_view key) {
  lookup(key);
  if (!has(key)) diagnostics_->add(where_, full_key(key), "missing; this key is required");
}

const toml::table* TableReader::table(std::string_view key) {
  const toml::node* node = lookup(key);
  if (node == nullptr) return nullptr;
  if (const auto* t = node->as_table()) return t;
  wrong_type(key, *node, "a table");
  return nullptr;
}

const toml::array* TableReader::array_of_tables(std::string_view key) {
  const toml::node* node = lookup(key);
  if (node == nullptr) return nullptr;
  const auto* a = node->as_array();
  if (a == nullptr || !a->is_array_of_tables()) {
    // An empty array is fine too (no entries).
    if (a != nullptr && a->empty()) return a;
    wrong_type(key, *node, ("an array of tables ([[" + std::string(key) + "]])").c_str());
    return nullptr;
  }
  return a;
}

void TableReader::reject_unknown() {
  if (table_ == nullptr) return;
  for (auto&& [k, node] : *table_) {
    const std::string_view name = k.str();
    if (std::find(known_.begin(), known_.end(), name) != known_.end()) continue;
    std::string problem = node.is_table() ? "unknown section" : "unknown key";
    // Suggest the nearest known key for a likely typo.
    const std::string* best = nullptr;
    size_t best_distance = 3;
    for (const auto& candidate : known_) {
      const size_t d = edit_distance(name, candidate);
      if (d < best_distance) {
        best_distance = d;
        best = &candidate;
      }
    }
    if (best != nullptr) problem += " (did you mean \"" + *best + "\"?)";
    diagnostics_->add(k.source(), full_key(name), problem);
  }
}

}  // namespace depthfuse::strict_toml
