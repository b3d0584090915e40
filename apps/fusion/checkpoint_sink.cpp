// Which CheckpointSink the fusion daemon gets: the SQLite scan store where it is built, else the
// sink that keeps nothing. Called once, by main(), before the daemon starts its threads.
#include "checkpoint_sink.hpp"

#if DEPTHFUSE_FUSION_HAS_STORE
#include "sqlite_checkpoint_sink.hpp"
#endif

namespace depthfuse::fusiond {

std::unique_ptr<CheckpointSink> make_checkpoint_sink(const AppConfig& config,
                                                     const std::string& scan_db_path) {
#if DEPTHFUSE_FUSION_HAS_STORE
  return std::make_unique<SqliteCheckpointSink>(config, SqliteSinkOptions{scan_db_path});
#else
  (void)config;
  (void)scan_db_path;
  return std::make_unique<NullCheckpointSink>();
#endif
}

}  // namespace depthfuse::fusiond
