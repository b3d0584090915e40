// The calling thread's scheduling niceness.
#pragma once

namespace depthfuse {

// Makes the calling thread a background one: niceness 10 (Linux schedules threads one by one, so
// this is the thread's, not the process's). For work that has seconds of slack, such as writing
// checkpoints. On the appliance's two cores, a frame's fusion runs as two halves, one per core;
// every millisecond another thread takes a core meanwhile lengthens the frame by as much, and a
// background thread waits for an idle core instead. Lowering one's priority needs no privilege;
// it is best effort, so a failure is ignored.
void make_background_thread();

}  // namespace depthfuse
