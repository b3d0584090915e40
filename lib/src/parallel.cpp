#include "parallel.hpp"

#include <condition_variable>
#include <mutex>
#include <system_error>
#include <thread>

#include <unistd.h>

namespace depthfuse::detail {
namespace {

// One thread for the second halves of run_pair, started on first use and kept for the process's
// life (never joined: it sleeps between tasks, and exits with the process). It inherits the
// scheduling priority of the thread that first splits work, which in the daemons is the fusion
// thread: the background writers (make_background_thread) never split theirs.
class PairThread {
 public:
  static PairThread* get() {
    // Leaked on purpose: a static's destructor at exit would join a thread that may never wake.
    static PairThread* instance = [] {
      auto* p = new PairThread;
      try {
        std::thread([p] { p->loop(); }).detach();
      } catch (const std::system_error&) {
        p->usable_ = false;
      }
      return p;
    }();
    // A forked child has no copy of the thread: it makes its own per call.
    return instance->usable_ && instance->pid_ == ::getpid() ? instance : nullptr;
  }

  // Takes the thread for one task, or returns false if another caller has it.
  bool try_take() {
    std::lock_guard<std::mutex> lock(mu_);
    if (taken_) return false;
    taken_ = true;
    return true;
  }

  // With the thread taken: runs task on it, first on the calling thread, and waits for both.
  void run(void (*task)(void*), void* context, void (*first)(void*), void* first_context) {
    {
      std::lock_guard<std::mutex> lock(mu_);
      task_ = task;
      context_ = context;
      done_ = false;
    }
    work_.notify_one();
    first(first_context);
    std::unique_lock<std::mutex> lock(mu_);
    finished_.wait(lock, [&] { return done_; });
    taken_ = false;
  }

 private:
  void loop() {
    std::unique_lock<std::mutex> lock(mu_);
    for (;;) {
      work_.wait(lock, [&] { return task_ != nullptr; });
      void (*task)(void*) = task_;
      void* context = context_;
      task_ = nullptr;
      lock.unlock();
      task(context);
      lock.lock();
      done_ = true;
      finished_.notify_one();
    }
  }

  std::mutex mu_;
  std::condition_variable work_;      // a task for the thread
  std::condition_variable finished_;  // the thread's task done
  bool taken_ = false;
  bool done_ = false;
  bool usable_ = true;
  const pid_t pid_ = ::getpid();
  void (*task_)(void*) = nullptr;
  void* context_ = nullptr;
};

}  // namespace

void run_second(void (*task)(void*), void* context, void (*first)(void*), void* first_context) {
  if (PairThread* pair = PairThread::get(); pair && pair->try_take()) {
    pair->run(task, context, first, first_context);
    return;
  }
  std::thread other;
  try {
    other = std::thread([task, context] { task(context); });
  } catch (const std::system_error&) {  // no thread to be had: do it here
    first(first_context);
    task(context);
    return;
  }
  first(first_context);
  other.join();
}

}  // namespace depthfuse::detail
