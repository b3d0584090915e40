#include "depthfuse/base/thread_priority.hpp"

#include <sys/resource.h>
#include <sys/syscall.h>
#include <unistd.h>

namespace depthfuse {

void make_background_thread() {
  constexpr int kBackgroundNice = 10;
  // Linux's setpriority(PRIO_PROCESS, tid) applies to the one thread (a POSIX deviation).
  const auto tid = static_cast<id_t>(::syscall(SYS_gettid));
  (void)::setpriority(PRIO_PROCESS, tid, kBackgroundNice);
}

}  // namespace depthfuse
