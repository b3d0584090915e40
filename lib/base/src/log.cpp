// The log's state: the program name, the thresholds parsed from the spec, and whether stderr is
// the systemd journal. Written once at start-up, read by any thread.
#include "depthfuse/base/log.hpp"

#include <sys/stat.h>
#include <unistd.h>

#include <atomic>
#include <cstdio>
#include <cstdlib>
#include <mutex>
#include <utility>
#include <vector>

namespace depthfuse::log {
namespace {

struct Thresholds {
  Level fallback = Level::Info;
  std::vector<std::pair<std::string, Level>> per_category;
};

std::mutex g_mutex;  // guards g_program and g_thresholds; serialises the writes to stderr
std::string g_program = "depthfuse";
Thresholds g_thresholds;
std::atomic<unsigned> g_generation{1};  // bumped by configure(); categories re-read then

bool parse_level(std::string_view word, Level* out) {
  static const std::pair<std::string_view, Level> kWords[] = {
      {"debug", Level::Debug}, {"info", Level::Info}, {"warning", Level::Warning},
      {"error", Level::Error}};
  for (const auto& [name, level] : kWords) {
    if (word == name) {
      *out = level;
      return true;
    }
  }
  return false;
}

bool parse_spec(std::string_view spec, Thresholds* out, std::string* error) {
  Thresholds parsed;
  while (!spec.empty()) {
    const size_t comma = spec.find(',');
    const std::string_view item = spec.substr(0, comma);
    spec = comma == std::string_view::npos ? std::string_view() : spec.substr(comma + 1);
    if (item.empty()) continue;
    const size_t eq = item.find('=');
    Level level;
    if (!parse_level(eq == std::string_view::npos ? item : item.substr(eq + 1), &level)) {
      *error = "log level '" + std::string(item) +
               "' is not one of debug, info, warning, error (or Category=level)";
      return false;
    }
    if (eq == std::string_view::npos) {
      parsed.fallback = level;
    } else {
      parsed.per_category.emplace_back(std::string(item.substr(0, eq)), level);
    }
  }
  *out = std::move(parsed);
  return true;
}

// $DEPTHFUSE_LOG applies until the program configures the log itself; a bad value is ignored
// (there is nobody to tell yet).
void apply_environment_once() {
  static std::once_flag once;
  std::call_once(once, [] {
    if (const char* env = std::getenv("DEPTHFUSE_LOG")) {
      std::string ignored;
      parse_spec(env, &g_thresholds, &ignored);
    }
  });
}

// systemd sets JOURNAL_STREAM to stderr's "device:inode" when stderr is the journal.
bool stderr_is_journal() {
  static const bool journal = [] {
    const char* env = std::getenv("JOURNAL_STREAM");
    struct stat st;
    if (!env || fstat(STDERR_FILENO, &st) != 0) return false;
    unsigned long long dev = 0, ino = 0;
    return std::sscanf(env, "%llu:%llu", &dev, &ino) == 2 &&
           dev == static_cast<unsigned long long>(st.st_dev) &&
           ino == static_cast<unsigned long long>(st.st_ino);
  }();
  return journal;
}

// Per-thread cache of the category thresholds of the current generation.
struct CachedThreshold {
  const Category* category = nullptr;
  unsigned generation = 0;
  Level threshold = Level::Info;
};

Level threshold_of(const Category& category) {
  std::lock_guard<std::mutex> lock(g_mutex);
  apply_environment_once();
  for (const auto& [name, level] : g_thresholds.per_category) {
    if (name == category.name()) return level;
  }
  return g_thresholds.fallback;
}

}  // namespace

Category::Category(const char* name) : name_(name) {}

bool Category::enabled(Level level) const {
  // A small per-thread cache keeps the common case free of locks: a few categories per thread.
  thread_local CachedThreshold cache[8];
  const unsigned generation = g_generation.load(std::memory_order_acquire);
  CachedThreshold& slot = cache[(reinterpret_cast<uintptr_t>(this) >> 4) % 8];
  if (slot.category != this || slot.generation != generation) {
    slot = {this, generation, threshold_of(*this)};
  }
  return level >= slot.threshold;
}

void set_program_name(std::string name) {
  std::lock_guard<std::mutex> lock(g_mutex);
  g_program = std::move(name);
}

std::string program_name() {
  std::lock_guard<std::mutex> lock(g_mutex);
  return g_program;
}

bool configure(std::string_view spec, std::string* error) {
  Thresholds parsed;
  if (!parse_spec(spec, &parsed, error)) return false;
  std::lock_guard<std::mutex> lock(g_mutex);
  apply_environment_once();  // so that it cannot overwrite this later
  g_thresholds = std::move(parsed);
  g_generation.fetch_add(1, std::memory_order_release);
  return true;
}

Message::~Message() {
  static const char* const kWords[] = {"debug", nullptr, "warning", nullptr};
  static const int kSyslogPriority[] = {7, 6, 4, 3};
  const int index = static_cast<int>(level_);
  std::string line;
  if (stderr_is_journal()) line = "<" + std::to_string(kSyslogPriority[index]) + ">";
  std::lock_guard<std::mutex> lock(g_mutex);
  line += g_program;
  line += ": ";
  if (kWords[index]) {
    line += kWords[index];
    line += ": ";
  }
  if (level_ == Level::Debug) {
    line += "[";
    line += category_.name();
    line += "] ";
  }
  line += out_.str();
  line += '\n';
  std::fwrite(line.data(), 1, line.size(), stderr);
}

}  // namespace depthfuse::log
