// Internal: the little parallelism the pipeline uses. The appliance has two cores; a frame's work
// splits into two halves that touch disjoint data, so one second thread is all it takes.
#pragma once

#include <type_traits>
#include <utility>

namespace depthfuse {

namespace detail {
// Runs task(context) on the process's pair thread, or on a new thread when the pair thread is
// taken (by another caller, or by a nested call), while the caller runs its own half. Returns
// once the task is done. Runs it on the calling thread if no thread can be had.
void run_second(void (*task)(void*), void* context, void (*first)(void*), void* first_context);
}  // namespace detail

// Runs first() on the calling thread and second() on another, and returns when both are done. With
// threads <= 1 it runs them one after the other on the calling thread. A frame makes a dozen such
// calls; the second thread is one kept for them rather than one created per call.
template <typename First, typename Second>
void run_pair(int threads, First&& first, Second&& second) {
  if (threads <= 1) {
    first();
    second();
    return;
  }
  using F = std::remove_reference_t<First>;
  using S = std::remove_reference_t<Second>;
  detail::run_second([](void* c) { (*static_cast<S*>(c))(); }, static_cast<void*>(&second),
                     [](void* c) { (*static_cast<F*>(c))(); }, static_cast<void*>(&first));
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
