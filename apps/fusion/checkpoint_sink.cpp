#include "checkpoint_sink.hpp"

namespace depthfuse::fusiond {

std::unique_ptr<CheckpointSink> make_checkpoint_sink(const AppConfig& config) {
  (void)config;
  // The SQLite scan store (lib/store) implements CheckpointSink in its own adapter and is returned
  // here once it is wired in; this build keeps no checkpoints.
  return std::make_unique<NullCheckpointSink>();
}

}  // namespace depthfuse::fusiond
