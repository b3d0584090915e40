#!/usr/bin/env bash
# The vectorised loops of the per-frame path come in two versions, the x86-64 baseline and AVX2
# (DF_VECTOR_CLONES), and the loader picks one by CPU. They are meant to give the same bytes: the
# same operations, no FMA. This CPU only ever runs one of them, so the test builds the CLI again
# without the clones and compares the two on a synthetic scan: the fused clouds and the refined
# trajectories must be identical, for `full` (fusion and six rounds of ICP) and `ylimaki17`.
#   vector_clones_same_results.sh <source dir> <build dir for the baseline> <generator>
#                                 <build type> <depthfuse with clones>
# Exit 77 (skipped) where there is nothing to compare: no AVX2 clones in the binary (not x86-64
# GCC), or a CPU without AVX2 (both versions would be the baseline).
set -euo pipefail
src="$1" bdir="$2" generator="$3" build_type="$4" DF="$5"

# (grep reads all of objdump's output: with -q it would stop early, and pipefail would see the
# SIGPIPE objdump then gets.)
clones() { objdump -d "$1" 2>/dev/null | grep -c '\.avx2>:' || true; }
if [[ $(clones "$DF") == 0 ]]; then
  echo "skipped: $DF has no AVX2 clones"; exit 77
fi
if ! grep -qw avx2 /proc/cpuinfo; then
  echo "skipped: this CPU has no AVX2, so it runs the baseline in both builds"; exit 77
fi

echo "building the CLI without the AVX2 clones in $bdir"
cmake -S "$src" -B "$bdir" -G "$generator" -DCMAKE_BUILD_TYPE="$build_type" \
  -DDEPTHFUSE_VECTOR_CLONES=OFF >"$bdir.configure.log" 2>&1 ||
  { cat "$bdir.configure.log"; exit 1; }
cmake --build "$bdir" --target depthfuse --parallel 2 >"$bdir.build.log" 2>&1 || { tail -50 "$bdir.build.log"; exit 1; }
BASE="$bdir/bin/depthfuse"
if [[ $(clones "$BASE") != 0 ]]; then
  echo "FAIL: $BASE still has AVX2 clones"; exit 1
fi

T=$(mktemp -d)
trap 'rm -rf "$T"' EXIT
"$DF" synth corner "$T/scan" --frames 12 --seed 3 >/dev/null
fails=0
for method in full ylimaki17; do
  for bin in "$DF" "$BASE"; do
    tag=$([[ $bin == "$DF" ]] && echo clones || echo baseline)
    "$bin" reconstruct "$T/scan" --poses "$T/scan/poses_perturbed.txt" --method "$method" \
      -o "$T/$method.$tag.ply" --trajectory-out "$T/$method.$tag.txt" >"$T/$method.$tag.log" 2>&1 ||
      { echo "FAIL: $tag $method"; cat "$T/$method.$tag.log"; exit 1; }
  done
  for ext in ply txt; do
    if cmp -s "$T/$method.clones.$ext" "$T/$method.baseline.$ext"; then
      echo "ok   $method: the same $ext ($(stat -c %s "$T/$method.clones.$ext") bytes)"
    else
      echo "FAIL $method: the $ext files differ"; cmp "$T/$method.clones.$ext" "$T/$method.baseline.$ext" || true
      fails=$((fails + 1))
    fi
  done
done
exit $((fails > 0))
