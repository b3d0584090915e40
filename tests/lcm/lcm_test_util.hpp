// Helpers for the LCM tests: a per-process loopback URL, child processes, a background listener.
#pragma once

#include <arpa/inet.h>
#include <fcntl.h>
#include <netinet/in.h>
#include <signal.h>
#include <sys/socket.h>
#include <sys/wait.h>
#include <unistd.h>

#include <atomic>
#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <functional>
#include <map>
#include <mutex>
#include <sstream>
#include <string>
#include <thread>
#include <vector>

#include <gtest/gtest.h>

#include "depthfuse/lcm/host_diagnosis.hpp"
#include "depthfuse/lcm/transport.hpp"

namespace depthfuse::testing {

inline std::string bin(const std::string& name) { return std::string(DEPTHFUSE_BIN_DIR) + "/" + name; }

// The ports a test may take: 10000..31999, away from LCM's default 7667 and below the kernel's
// ephemeral range (32768 up by default). In that range any sending socket's automatic bind can hold
// the port without SO_REUSEADDR, and the test's receiver then cannot bind it.
inline int test_port(int seed) { return 10000 + (seed < 0 ? -seed : seed) % 22000; }

// Whether a receiver can bind `port` now, as the transport binds it (SO_REUSEADDR).
inline bool udp_port_bindable(int port) {
  const int fd = ::socket(AF_INET, SOCK_DGRAM | SOCK_CLOEXEC, 0);
  if (fd < 0) return false;
  const int one = 1;
  sockaddr_in local{};
  local.sin_family = AF_INET;
  local.sin_addr.s_addr = htonl(INADDR_ANY);
  local.sin_port = htons(static_cast<uint16_t>(port));
  const bool ok = ::setsockopt(fd, SOL_SOCKET, SO_REUSEADDR, &one, sizeof(one)) == 0 &&
                  ::bind(fd, reinterpret_cast<const sockaddr*>(&local), sizeof(local)) == 0;
  ::close(fd);
  return ok;
}

// Each test process gets its own udpm port, chosen once from its process id (so tests running
// side by side do not hear each other), moved on past any port something else holds.
inline std::string test_url() {
  static const int port = [] {
    const int first = static_cast<int>(::getpid());
    for (int i = 0; i < 64; ++i)
      if (udp_port_bindable(test_port(first + i))) return test_port(first + i);
    return test_port(first);
  }();
  return lcm::udpm_url(port);
}

// Fails the test with the route diagnosis when multicast cannot work on this host.
inline void require_multicast_route(const std::string& url) {
  auto parsed = lcm::parse_lcm_url(url);
  ASSERT_TRUE(parsed.is_ok()) << parsed.status().to_string();
  const auto d = lcm::diagnose_lcm_url(*parsed);
  ASSERT_TRUE(d.route.is_ok())
      << "these tests need LCM multicast on loopback: " << d.route.message()
      << " (tools/setup.sh and tools/lcm/route add the route)";
}

// The directories temp_dir() made go when the test program ends with no test failed. After a
// failure, or with DEPTHFUSE_KEEP_TEST_FILES set, they stay and are named: the daemons' logs are in
// them.
class TempDirCleanup : public ::testing::Environment {
 public:
  void add(const std::filesystem::path& dir) {
    std::lock_guard<std::mutex> lock(mutex_);
    dirs_.push_back(dir);
  }
  void TearDown() override {
    std::lock_guard<std::mutex> lock(mutex_);
    const bool keep = std::getenv("DEPTHFUSE_KEEP_TEST_FILES") ||
                      ::testing::UnitTest::GetInstance()->Failed();
    for (const auto& dir : dirs_) {
      std::error_code ec;
      if (keep) std::fprintf(stderr, "kept %s\n", dir.c_str());
      else std::filesystem::remove_all(dir, ec);
    }
    dirs_.clear();
  }

 private:
  std::mutex mutex_;
  std::vector<std::filesystem::path> dirs_;
};

// Registered before main (gtest's documented way for a program without its own main).
inline TempDirCleanup* const temp_dir_cleanup = static_cast<TempDirCleanup*>(
    ::testing::AddGlobalTestEnvironment(new TempDirCleanup));

inline std::string temp_dir(const std::string& tag) {
  auto dir = std::filesystem::temp_directory_path() /
             ("depthfuse-" + tag + "-" + std::to_string(::getpid()));
  std::filesystem::remove_all(dir);
  std::filesystem::create_directories(dir);
  temp_dir_cleanup->add(dir);
  return dir.string();
}

inline std::string read_text(const std::string& path) {
  std::ifstream in(path);
  std::stringstream ss;
  ss << in.rdbuf();
  return ss.str();
}

// A child process with stdout+stderr in a log file; SIGTERM and reaped when destroyed.
class Process {
 public:
  Process(std::vector<std::string> argv, std::string log_path)
      : argv_(std::move(argv)), log_path_(std::move(log_path)) {
    pid_ = ::fork();
    if (pid_ == 0) {
      const int fd = ::open(log_path_.c_str(), O_WRONLY | O_CREAT | O_TRUNC | O_CLOEXEC, 0644);
      if (fd >= 0) {
        ::dup2(fd, 1);
        ::dup2(fd, 2);
      }
      std::vector<char*> args;
      for (auto& a : argv_) args.push_back(a.data());
      args.push_back(nullptr);
      ::execv(args[0], args.data());
      std::perror("execv");
      ::_exit(127);
    }
  }
  ~Process() {
    if (running()) {
      signal(SIGTERM);
      if (!wait(std::chrono::seconds(60))) {
        signal(SIGKILL);
        wait(std::chrono::seconds(5));
      }
    }
  }
  Process(const Process&) = delete;
  Process& operator=(const Process&) = delete;

  pid_t pid() const { return pid_; }
  bool running() {
    if (exited_ || pid_ <= 0) return false;
    int status = 0;
    const pid_t r = ::waitpid(pid_, &status, WNOHANG);
    if (r == pid_) {
      record(status);
      return false;
    }
    return true;
  }
  void signal(int sig) {
    if (!exited_ && pid_ > 0) ::kill(pid_, sig);
  }
  // True when it exited within the timeout.
  bool wait(std::chrono::milliseconds timeout) {
    const auto deadline = std::chrono::steady_clock::now() + timeout;
    while (running()) {
      if (std::chrono::steady_clock::now() > deadline) return false;
      std::this_thread::sleep_for(std::chrono::milliseconds(20));
    }
    return true;
  }
  // Exit code, or 128 + signal; -1 while running.
  int exit_code() const { return exit_code_; }
  std::string log() const { return read_text(log_path_); }

 private:
  void record(int status) {
    exited_ = true;
    exit_code_ = WIFEXITED(status) ? WEXITSTATUS(status) : 128 + WTERMSIG(status);
  }
  std::vector<std::string> argv_;
  std::string log_path_;
  pid_t pid_ = -1;
  bool exited_ = false;
  int exit_code_ = -1;
};

// Runs a command to completion; returns its exit code and its output.
inline int run_command(std::vector<std::string> argv, const std::string& log_path, std::string* output,
                       std::chrono::seconds timeout = std::chrono::seconds(60)) {
  Process p(std::move(argv), log_path);
  if (!p.wait(timeout)) {
    p.signal(SIGKILL);
    p.wait(std::chrono::seconds(5));
  }
  if (output) *output = p.log();
  return p.exit_code();
}

// Polls `pred` until true or the timeout; returns pred's last value.
inline bool eventually(const std::function<bool()>& pred, std::chrono::milliseconds timeout,
                       std::chrono::milliseconds step = std::chrono::milliseconds(50)) {
  const auto deadline = std::chrono::steady_clock::now() + timeout;
  while (!pred()) {
    if (std::chrono::steady_clock::now() > deadline) return pred();
    std::this_thread::sleep_for(step);
  }
  return true;
}

// Receives in a background thread; handlers run there.
class Listener {
 public:
  explicit Listener(const std::string& url) {
    auto opened = lcm::LcmTransport::open(url);
    if (!opened) {
      error_ = opened.status().to_string();
      return;
    }
    lcm_ = std::move(opened).value();
  }
  ~Listener() { stop(); }
  const std::string& error() const { return error_; }
  lcm::LcmTransport* lcm() { return lcm_.get(); }
  void subscribe(const std::string& channel, lcm::LcmTransport::Handler h) {
    lcm_->subscribe(channel, std::move(h));
  }
  void start() {
    thread_ = std::thread([this] {
      while (!stop_) (void)lcm_->handle(20);
    });
  }
  void stop() {
    stop_ = true;
    if (thread_.joinable()) thread_.join();
  }

 private:
  std::unique_ptr<lcm::LcmTransport> lcm_;
  std::string error_;
  std::atomic<bool> stop_{false};
  std::thread thread_;
};

}  // namespace depthfuse::testing
