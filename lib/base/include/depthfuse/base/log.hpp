// The levelled log every depthfuse program writes its diagnostics through, after libcamera's
// LOG(Category, Level):
//
//   DF_LOG_CATEGORY(Store)                      // once per .cpp, at namespace scope
//   DF_LOG(Store, Warning) << "recovered " << n << " frames";
//
// A line goes to stderr whole, as "<program>: warning: <message>" (no level word for Info and
// Error, the level's word otherwise; Debug lines also name their category). Under systemd the line
// starts with the syslog priority ("<4>"), so that `journalctl -p warning` filters it.
//
// What is shown is set once at start-up from --log-level or $DEPTHFUSE_LOG: a level ("debug"), or a
// default and per-category levels ("warning,Store=debug"). The default shows Info and above. A
// message below its category's threshold costs one comparison: its stream is never built.
#pragma once

#include <sstream>
#include <string>
#include <string_view>

namespace depthfuse::log {

enum class Level { Debug = 0, Info = 1, Warning = 2, Error = 3 };

// A named part of a program whose messages are shown or hidden together.
class Category {
 public:
  explicit Category(const char* name);
  const char* name() const { return name_; }
  bool enabled(Level level) const;

 private:
  const char* name_;
};

// The prefix of every line, e.g. "depthfuse-fusion" or "depthfuse export".
void set_program_name(std::string name);
std::string program_name();

// Parses a spec as described above; on a malformed spec returns false, says why in `error`, and
// changes nothing.
bool configure(std::string_view spec, std::string* error);

// One message; written when it goes out of scope.
class Message {
 public:
  Message(const Category& category, Level level) : category_(category), level_(level) {}
  Message(const Message&) = delete;
  Message& operator=(const Message&) = delete;
  ~Message();
  std::ostream& stream() { return out_; }

 private:
  const Category& category_;
  Level level_;
  std::ostringstream out_;
};

// Turns the stream expression into void, the type of the other branch of DF_LOG's conditional.
struct Voidify {
  void operator&(std::ostream&) {}
};

}  // namespace depthfuse::log

// Defines the category `name` for this translation unit.
#define DF_LOG_CATEGORY(name)                                              \
  [[maybe_unused]] static const ::depthfuse::log::Category& df_log_##name() { \
    static const ::depthfuse::log::Category category(#name);              \
    return category;                                                       \
  }

// One expression, so that it is safe as the body of an unbraced if/else.
#define DF_LOG(category, level)                                                    \
  !df_log_##category().enabled(::depthfuse::log::Level::level)                     \
      ? (void)0                                                                    \
      : ::depthfuse::log::Voidify() &                                              \
            ::depthfuse::log::Message(df_log_##category(), ::depthfuse::log::Level::level).stream()
