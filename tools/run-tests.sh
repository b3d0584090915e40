#!/usr/bin/env bash
# The whole test suite: builds what changed, then runs every CTest test (unit, end-to-end over real
# LCM on loopback, SQLite crash tests, packaging). Run tools/setup.sh once before.
set -euo pipefail
cd "$(dirname "$0")/.."
cmake --build build -j"$(nproc)"
ctest --test-dir build --output-on-failure -j"$(nproc)" "$@"
