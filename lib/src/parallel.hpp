// Internal: the little parallelism the pipeline uses. The appliance has two cores; a frame's work
// splits into two halves that touch disjoint data, so a second thread per call is all it takes.
#pragma once

#include <system_error>
#include <thread>
#include <utility>

namespace depthfuse {

// Runs first() on the calling thread and second() on another, and returns when both are done. With
// threads <= 1 it runs them one after the other on the calling thread.
template <typename First, typename Second>
void run_pair(int threads, First&& first, Second&& second) {
  if (threads <= 1) {
    first();
    second();
    return;
  }
  std::thread other;
  try {
    other = std::thread(std::forward<Second>(second));
  } catch (const std::system_error&) {  // no thread to be had: do it here
    first();
    second();
    return;
  }
  first();
  other.join();
}

// Runs pass(0, count / 2) and pass(count / 2, count) through run_pair: a pass over the two halves
// of a range (an image's rows, or its pixels). The pass must write only the part it is given.
template <typename Index, typename Pass>
void run_halves(int threads, Index count, Pass&& pass) {
  run_pair(threads, [&] { pass(Index{0}, count / 2); }, [&] { pass(count / 2, count); });
}

template <typename Pass>
void run_row_halves(int threads, int rows, Pass&& pass) {
  run_halves(threads, rows, std::forward<Pass>(pass));
}

}  // namespace depthfuse
