#!/usr/bin/env bash
# The whole test suite: builds what changed, then runs every CTest test (unit, end-to-end over real
# LCM on loopback, SQLite crash tests, packaging), then every fuzz target for a bounded time
# (tools/fuzz.sh; DEPTHFUSE_FUZZ_SECONDS per target, 20 by default). Run tools/setup.sh once before.
set -euo pipefail
cd "$(dirname "$0")/.."
cmake --build build -j"$(nproc)"
status=0
ctest --test-dir build --output-on-failure -j"$(nproc)" "$@" || status=$?

# CTest says that a test was skipped, not why; GoogleTest wrote the reason into the test's log.
log=build/Testing/Temporary/LastTest.log
if [[ -f $log ]] && grep -q '^\[  SKIPPED \] ' "$log"; then
  echo "Skipped, and why:"
  awk '/: Skipped$/ { why = ""; on = 1; next }
       /^\[  SKIPPED \] / { if (on) print "  " $4 ": " why; on = 0; next }
       on && NF { why = why (why == "" ? "" : " ") $0 }' "$log"
fi

# Every input that arrives from outside (udpm datagrams, LCM messages, PLY, PNG, config, blobs)
# under libFuzzer with ASan and UBSan, in its own clang build (build-fuzz/).
tools/fuzz.sh --seconds "${DEPTHFUSE_FUZZ_SECONDS:-20}" || status=1
exit "$status"
