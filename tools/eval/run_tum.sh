#!/usr/bin/env bash
# The real-data part of the evaluation (issue 2, "The evaluation" 3): TUM RGB-D fr1/xyz
#   (a) with the ground-truth poses: the three methods and Open3D's ScalableTSDFVolume (5 mm);
#   (b) with perturbed poses (ground truth + N(0, 2 cm) per axis, N(0, 1 deg) about a random axis,
#       seed 1; tools/eval/perturb_poses.py): full, and Open3D on the same poses, whose ATE is the
#       ATE before re-registration;
#   (c) tracked from the first frame, without poses (full --track).
# There is no geometric ground truth for fr1/xyz: distances and Jaccard indices are measured against
# the `full` reconstruction with ground-truth poses (the reference), with Open3D on the same poses
# as a peer. Each reconstruction has its own gauge (re-registration moves all poses together, a
# tracked one starts at the identity) and the camera path of these frames is nearly planar, so a
# position-only trajectory alignment does not pin the rotation: every cloud is placed on the
# reference by a rigid ICP fit (tools/eval/align_to_reference.py) and then evaluated with --no-align.
# The ATE is the usual one (`depthfuse eval --trajectory`).
#
#   tools/eval/run_tum.sh [outdir]                (default /tmp/depthfuse-eval/tum)
#
# Environment: TUM_DIR (default ../shared/datasets/tum_fr1_xyz from the repo), STRIDE (6),
# MAX_FRAMES (40), DEPTHFUSE (build/bin/depthfuse), PYTHON_O3D (/usr/bin/python3),
# ITERATIONS (empty = the config's default), REUSE=1 keeps clouds and reports already in outdir.
# Runs one thing at a time: the machine is shared.
set -euo pipefail

repo=$(cd "$(dirname "$0")/../.." && pwd)
out=${1:-/tmp/depthfuse-eval/tum}
data=${TUM_DIR:-$repo/../shared/datasets/tum_fr1_xyz}
DF=${DEPTHFUSE:-$repo/build/bin/depthfuse}
PY=${PYTHON_O3D:-/usr/bin/python3}
STRIDE=${STRIDE:-6}
MAX_FRAMES=${MAX_FRAMES:-40}
cam="$repo/tools/eval/tum_fr1_camera.toml"
iter_args=()
[[ -n "${ITERATIONS:-}" ]] && iter_args=(--iterations "$ITERATIONS")

if [[ ! -f "$data/depth.txt" || ! -f "$data/groundtruth.txt" ]]; then
  echo "run_tum.sh: no TUM fr1/xyz at $data (depth.txt, groundtruth.txt); skipping the real-data evaluation"
  exit 0
fi
[[ -x "$DF" ]] || { echo "run_tum.sh: no $DF (build it: ninja -C build depthfuse)" >&2; exit 1; }
"$PY" -c "import open3d, numpy" 2>/dev/null || { echo "run_tum.sh: $PY lacks open3d/numpy (apt-get install python3-open3d)" >&2; exit 1; }
mkdir -p "$out"

REUSE=${REUSE:-0}
# shellcheck source=tools/eval/common.sh
source "$repo/tools/eval/common.sh"

# The frames every tool uses: every STRIDE-th depth frame with a ground-truth pose within 20 ms.
sub="$out/fr1_xyz"
if ! have "$sub/depth.txt"; then
  rm -rf "$sub"
  "$PY" "$repo/tools/eval/tum_subset.py" "$data" "$sub" --stride "$STRIDE" --max-frames "$MAX_FRAMES" \
    --camera "$cam" > "$out/subset.log"
  "$PY" "$repo/tools/eval/perturb_poses.py" "$sub" "$out/poses_perturbed.txt" --sigma-m 0.02 --sigma-deg 1 \
    --seed 1 > "$out/perturb.log"
  # The ground truth at the frames' times: the poses Open3D integrates (the same association).
  "$PY" "$repo/tools/eval/perturb_poses.py" "$sub" "$out/groundtruth_frames.txt" --sigma-m 0 --sigma-deg 0 \
    > /dev/null
fi
cat "$out/subset.log" "$out/perturb.log"

manifest="$out/tum.manifest.tsv"
: > "$manifest"
ref="$out/full.groundtruth.ply"

reconstruct() {  # TAG METHOD pose-args...
  local tag=$1 method=$2
  shift 2
  run "$tag" "$DF" reconstruct "$sub" --camera "$cam" --method "$method" "$@" "${iter_args[@]}" \
    -o "$out/$tag.ply" --trajectory-out "$out/$tag.traj.txt" --report "$out/$tag.reconstruct.txt"
}

open3d() {  # TAG POSEFILE
  run "$1" "$PY" "$repo/tools/eval/open3d_tsdf.py" "$sub" --camera "$cam" --poses "$2" -o "$out/$1.ply"
}

# evaluate TAG LABEL POSES TRAJECTORY [--start-from-trajectory]: ICP onto the reference, then eval.
evaluate() {
  local tag=$1 label=$2 poses=$3 traj=$4 start=()
  [[ ${5:-} == --start-from-trajectory ]] && start=(--trajectory "$traj" --groundtruth "$sub/groundtruth.txt")
  if ! have "$out/$tag.eval.txt"; then
    log "$tag: rigid fit onto the reference"
    "$PY" "$repo/tools/eval/align_to_reference.py" "$out/$tag.ply" "$ref" "$out/$tag.aligned.ply" "${start[@]}" \
      > "$out/$tag.align.log" 2>&1
    log "$tag: eval against the reference"
    "$DF" eval "$sub" "$out/$tag.aligned.ply" --no-align --trajectory "$traj" --reference "$ref" \
      --label "$label ($poses)" --out "$out/$tag.eval" > "$out/$tag.eval.log" 2>&1
  fi
  printf '%s\t%s\t%s\t%s\t%s\n' "$label" "$poses" "$out/$tag.eval.txt" "$(cat "$out/$tag.seconds")" \
    "$out/$tag.eval.errors.csv" >> "$manifest"
}

# (a) ground-truth poses; full is also the reference (its own row has the counts and the ATE only).
reconstruct full.groundtruth full --poses "$sub/groundtruth.txt"
if ! have "$out/full.groundtruth.eval.txt"; then
  "$DF" eval "$sub" "$ref" --trajectory "$out/full.groundtruth.traj.txt" --label "full = reference" \
    --out "$out/full.groundtruth.eval" > "$out/full.groundtruth.eval.log" 2>&1
fi
printf '%s\t%s\t%s\t%s\t\n' "full = reference" groundtruth "$out/full.groundtruth.eval.txt" \
  "$(cat "$out/full.groundtruth.seconds")" >> "$manifest"
for method in ylimaki17 kyostila13; do
  reconstruct "$method.groundtruth" "$method" --poses "$sub/groundtruth.txt"
  evaluate "$method.groundtruth" "$method" groundtruth "$out/$method.groundtruth.traj.txt"
done
open3d open3d.groundtruth "$sub/groundtruth.txt"
evaluate open3d.groundtruth "open3d-tsdf 5 mm" groundtruth "$out/groundtruth_frames.txt"

# (b) perturbed poses: Open3D keeps them, so its ATE is the ATE before re-registration.
open3d open3d.perturbed "$out/poses_perturbed.txt"
evaluate open3d.perturbed "open3d-tsdf 5 mm" "perturbed (before)" "$out/poses_perturbed.txt"
reconstruct full.perturbed full --poses "$out/poses_perturbed.txt"
evaluate full.perturbed full "perturbed (after)" "$out/full.perturbed.traj.txt"

# (c) tracked from the first frame, no poses: its cloud starts from the trajectory's fit.
reconstruct full.tracked full --track
evaluate full.tracked full "tracked, no poses" "$out/full.tracked.traj.txt" --start-from-trajectory

{
  echo "<!-- written by tools/eval/run_tum.sh -->"
  echo "Run $(date -u +%Y-%m-%dT%H:%MZ) on $(hostname) ($(nproc) cores, load $(cut -d' ' -f1-3 /proc/loadavg)),"
  echo "depthfuse $(git -C "$repo" rev-parse --short HEAD 2>/dev/null || echo '?') ($DF, built $(date -u -r "$DF" +%Y-%m-%dT%H:%MZ)), $("$PY" -c 'import open3d; print("Open3D", open3d.__version__)')."
  echo "Frames: $(cat "$out/subset.log")"
  echo "Perturbed poses: $(cat "$out/perturb.log")"
  echo
  "$PY" "$repo/tools/eval/collect.py" "$manifest" --svg "$out/tum.errors.svg" \
    --title "TUM fr1/xyz, every ${STRIDE}th frame, at most $MAX_FRAMES; distances to full with ground-truth poses"
  echo "Rigid fits onto the reference (tools/eval/align_to_reference.py):"
  echo
  for f in "$out"/*.align.log; do echo "- $(basename "$f" .align.log): $(tail -1 "$f" | sed 's/^[^:]*: //')"; done
  echo
  echo "Cumulative curves: $out/tum.errors.svg (per cloud: $out/*.eval.errors.png)"
} > "$out/tables.md"
cat "$out/tables.md"
log "tables: $out/tables.md"
