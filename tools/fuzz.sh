#!/usr/bin/env bash
# Fuzzes every input depthfuse takes from outside (tests/fuzz: udpm datagrams, LCM messages, ...)
# with libFuzzer, AddressSanitizer and UndefinedBehaviorSanitizer, in a clang build in build-fuzz/.
# Prints, per target, the executions, the coverage reached, and any crash with its reproducer.
#
#   tools/fuzz.sh                 each target for 20 s (what tools/run-tests.sh runs)
#   tools/fuzz.sh --seconds 600   longer, as a benchmark; the figures go to docs/results.md
#
# Needs clang and its fuzzer runtime (Debian: clang libclang-rt-14-dev; tools/setup.sh installs
# them). A crash leaves crash-* / leak-* / oom-* files in build-fuzz/tests/fuzz/.
set -euo pipefail
cd "$(dirname "$0")/.."

seconds=20
while (($#)); do
  case "$1" in
    --seconds)
      [[ ${2:-} =~ ^[1-9][0-9]*$ ]] || { echo "fuzz: --seconds needs a whole number > 0" >&2; exit 2; }
      seconds=$2
      shift ;;
    -h|--help) sed -n '2,11s/^# \{0,1\}//p' "$0"; exit 0 ;;
    *) echo "fuzz: unknown option '$1' (see --help)" >&2; exit 2 ;;
  esac
  shift
done
for tool in clang clang++; do
  command -v "$tool" >/dev/null || { echo "fuzz: $tool is missing (Debian: clang libclang-rt-14-dev)" >&2; exit 1; }
done

mkdir -p build-fuzz
cmake -S . -B build-fuzz -G Ninja -DCMAKE_BUILD_TYPE=RelWithDebInfo \
  -DCMAKE_C_COMPILER=clang -DCMAKE_CXX_COMPILER=clang++ -DDEPTHFUSE_FUZZ=ON \
  -DDEPTHFUSE_VECTOR_CLONES=OFF -DDEPTHFUSE_FUZZ_SECONDS="$seconds" > build-fuzz/build.log 2>&1 ||
  { tail -n 30 build-fuzz/build.log >&2; echo "fuzz: configuring the clang build failed" >&2; exit 1; }
cmake --build build-fuzz -j"$(nproc)" --target fuzz_all >> build-fuzz/build.log 2>&1 ||
  { tail -n 40 build-fuzz/build.log >&2; echo "fuzz: building the fuzz targets failed" >&2; exit 1; }

status=0
ctest --test-dir build-fuzz -L fuzz --output-on-failure > build-fuzz/fuzz.log 2>&1 || status=$?

# libFuzzer ends each run with "#N DONE cov: C ft: F corp: ..." and "Done N runs in S second(s)".
echo "fuzzing, ${seconds} s per target:"
printf '  %-22s %12s %8s %8s\n' target executions cov features
log=build-fuzz/Testing/Temporary/LastTest.log
awk '
  /^[0-9]+\/[0-9]+ Testing: / { target = $3 }
  /DONE +cov: / { for (i = 1; i <= NF; ++i) { if ($i == "cov:") cov = $(i + 1); if ($i == "ft:") ft = $(i + 1) } }
  /^Done [0-9]+ runs/ { printf "  %-22s %12s %8s %8s\n", target, $2, cov, ft }
' "$log"
if ((status != 0)); then
  grep -E "^(==[0-9]+==ERROR|SUMMARY|artifact_prefix|Test unit written)" build-fuzz/fuzz.log | head -20 >&2 || true
  echo "fuzz: a target failed; build-fuzz/fuzz.log has its output" >&2
fi
tail -n 3 build-fuzz/fuzz.log
exit "$status"
