// Internal: the solver's diagnostics (Ceres writes through glog) into depthfuse's levelled log.
#pragma once

namespace depthfuse {

// Once per process, before the first solve: unless the program set glog up itself, glog writes no
// files and nothing on stderr, and its warnings and errors go to DF_LOG(Solver, ...) instead.
// Thread-safe; later calls do nothing.
void route_solver_log();

}  // namespace depthfuse
