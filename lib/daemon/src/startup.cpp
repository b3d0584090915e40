// The start-up of every program (see startup.hpp). Runs once, on the main thread, before the
// program starts any thread of its own.
#include "depthfuse/daemon/startup.hpp"

#include <cstdio>
#include <exception>

#include "depthfuse/base/log.hpp"

DF_LOG_CATEGORY(Startup)

namespace depthfuse::daemon {
namespace {

constexpr const char* kKeyFileUsage =
    "  --key-file FILE   the rig key that signs and verifies LCM messages (default: the config's\n"
    "                    lcm.key_file, /etc/depthfuse/rig.key; a missing file is an error);\n"
    "                    \"\" for none (the bus stays on this host)\n";
constexpr const char* kLogLevelUsage =
    "  --log-level SPEC  which messages to show: debug, info, warning or error, also per part\n"
    "                    (\"warning,Capture=debug\"); default info, or $DEPTHFUSE_LOG\n";

// The common options this program takes.
std::vector<std::string> common_options(const Program& program) {
  std::vector<std::string> names = {"log-level"};
  if (program.reads_config) names.push_back("config");
  if (program.uses_lcm) names.insert(names.end(), {"lcm", "key-file"});
  return names;
}

void print_usage(const Program& program, FILE* out) {
  std::fputs(program.usage.c_str(), out);
  if (program.uses_lcm) std::fputs(kKeyFileUsage, out);
  std::fputs(kLogLevelUsage, out);
}

}  // namespace

Result<AppConfig> load_config(const Args& args) {
  if (!args.has("config")) return AppConfig{};
  return load_app_config(args.get("config"));
}

Startup::Startup(Program program, int argc, char** argv)
    : program_(std::move(program)),
      args_(argc, argv, program_.flags, program_.optional_values) {
  log::set_program_name(program_.name);
  if (args_.has("help")) {
    print_usage(program_, stdout);
    exit_code_ = 0;
    return;
  }
  if (!args_.ok()) {
    exit_code_ = usage_error(args_.error());
    return;
  }
  std::vector<std::string> known = program_.options;
  known.insert(known.end(), program_.flags.begin(), program_.flags.end());
  known.insert(known.end(), program_.optional_values.begin(), program_.optional_values.end());
  const std::vector<std::string> common = common_options(program_);
  known.insert(known.end(), common.begin(), common.end());
  if (const std::string bad = args_.unknown(known); !bad.empty()) {
    exit_code_ = usage_error("unknown option " + bad);
    return;
  }
  if (args_.positional().size() > program_.max_positional) {
    exit_code_ = usage_error("unexpected argument '" + args_.positional()[program_.max_positional] + "'");
    return;
  }
  if (args_.has("log-level")) {
    std::string error;
    if (!log::configure(args_.get("log-level"), &error)) {
      exit_code_ = usage_error("--log-level: " + error);
      return;
    }
  }
  auto loaded = load_config(args_);
  if (!loaded) {
    DF_LOG(Startup, Error) << loaded.status().to_string();
    exit_code_ = 2;
    return;
  }
  config_ = std::move(loaded).value();
  if (args_.has("lcm")) {
    // An empty URL would quietly become liblcm's default bus, another one than the rig's.
    if (args_.get("lcm").empty()) {
      exit_code_ = usage_error("--lcm needs a URL, e.g. " + lcm::default_lcm_url());
      return;
    }
    config_.lcm.url = args_.get("lcm");
  }
  if (args_.has("key-file")) config_.lcm.key_file = args_.get("key-file");
}

int Startup::usage_error(const std::string& problem) const {
  DF_LOG(Startup, Error) << problem;
  print_usage(program_, stderr);
  return 2;
}

Result<std::optional<lcm::RigKey>> Startup::rig_key() const {
  const std::string& path = config_.lcm.key_file;
  if (path.empty()) return std::optional<lcm::RigKey>();
  // A key file that is named but missing or unusable is a broken rig, not an open one: running on
  // without a key would open the bus to anyone, unseen.
  auto loaded = lcm::RigKey::load(path);
  if (!loaded)
    return Status(loaded.status().code(),
                  loaded.status().message() + " (lcm.key_file, --key-file; \"\" runs without "
                                              "a key, on this host only: docs/protocol.md, "
                                              "\"Authentication\")");
  return std::optional<lcm::RigKey>(*loaded);
}

std::unique_ptr<lcm::LcmTransport> Startup::open_lcm() const {
  const LcmConfig& config = config_.lcm;
  auto loaded = rig_key();
  if (!loaded) {
    DF_LOG(Startup, Error) << loaded.status().to_string();
    return nullptr;
  }
  const std::optional<lcm::RigKey>& key = *loaded;
  std::string url = config.url;
  if (!key) {
    std::string warning = "no rig key (lcm.key_file is empty): LCM messages are neither signed "
                          "nor verified, so anyone who can reach the bus can send frames and "
                          "commands";
    // Unauthenticated traffic stays on this host.
    if (auto parsed = lcm::parse_lcm_url(url); parsed && parsed->ttl > 0) {
      url = lcm::url_with_ttl0(*parsed);
      warning += "; ttl=" + std::to_string(parsed->ttl) + " of the LCM URL is replaced by ttl=0";
    }
    DF_LOG(Startup, Warning) << warning << " (docs/protocol.md, \"Authentication\")";
  }
  std::vector<std::string> warnings;
  auto opened = lcm::LcmTransport::open(url, &warnings);
  for (const auto& w : warnings) DF_LOG(Startup, Warning) << w;
  if (!opened) {
    DF_LOG(Startup, Error) << opened.status().to_string();
    return nullptr;
  }
  auto transport = std::move(opened).value();
  if (key) {
    transport->authenticate(*key, static_cast<int64_t>(config.max_clock_skew_s * 1e6));
    DF_LOG(Startup, Debug) << "LCM messages signed and verified with rig key "
                           << key->fingerprint() << " (" << config.key_file << ")";
  }
  return transport;
}

int run_main(const std::function<int()>& body) {
  try {
    return body();
  } catch (const std::exception& e) {
    DF_LOG(Startup, Error) << "unexpected error: " << e.what();
  } catch (...) {
    DF_LOG(Startup, Error) << "unexpected error (not a std::exception)";
  }
  return 1;
}

}  // namespace depthfuse::daemon
