#!/usr/bin/env bash
# The synthetic part of the evaluation (issue 2, "The evaluation" 1 and 2): the synthetic corner and
# room, from perturbed poses (2 cm / 1 degree, the synthetic source's noise model) and from the
# ground-truth poses; the three methods and Open3D's ScalableTSDFVolume (5 mm voxels) side by side on
# the same frames with the same poses; `depthfuse eval` on every cloud; one markdown table per scene.
#
#   tools/eval/run_synthetic.sh [outdir]          (default /tmp/depthfuse-eval/synthetic)
#
# Every cloud is placed in the truth's frame by its trajectory's rigid alignment to the ground truth
# (what `depthfuse eval --trajectory` does). The clouds fused from the perturbed poses as given
# (ylimaki17, kyostila13, Open3D) are evaluated a second time without that alignment ("not aligned"):
# their poses are the truth plus zero-mean noise, and the position-only alignment of a noisy, nearly
# planar trajectory adds a rigid motion of its own.
#
# Environment: DEPTHFUSE (the CLI, default build/bin/depthfuse), PYTHON_O3D (a Python with Open3D,
# default /usr/bin/python3), SCENES ("corner room"), CORNER_FRAMES (30), ROOM_FRAMES (40), SEED (1),
# POSE_NOISE_M (0.02), POSE_NOISE_DEG (1), ITERATIONS (outer iterations; empty = the config's default),
# REUSE=1 keeps the data, clouds and reports already in outdir and only makes what is missing.
# Everything runs one after the other: the machine is shared.
set -euo pipefail

repo=$(cd "$(dirname "$0")/../.." && pwd)
out=${1:-/tmp/depthfuse-eval/synthetic}
DF=${DEPTHFUSE:-$repo/build/bin/depthfuse}
PY=${PYTHON_O3D:-/usr/bin/python3}
SCENES=${SCENES:-corner room}
SEED=${SEED:-1}
NOISE_M=${POSE_NOISE_M:-0.02}
NOISE_DEG=${POSE_NOISE_DEG:-1}
REUSE=${REUSE:-0}
iter_args=()
[[ -n "${ITERATIONS:-}" ]] && iter_args=(--iterations "$ITERATIONS")

[[ -x "$DF" ]] || { echo "run_synthetic.sh: no $DF (build it: ninja -C build depthfuse)" >&2; exit 1; }
"$PY" -c "import open3d" 2>/dev/null || { echo "run_synthetic.sh: $PY has no open3d (apt-get install python3-open3d)" >&2; exit 1; }
mkdir -p "$out"

# shellcheck source=tools/eval/common.sh
source "$repo/tools/eval/common.sh"

# evaluate TAG EVAL-TAG METHOD POSES-LABEL TRAJECTORY [eval options]: one row of the table.
evaluate() {
  local tag=$1 etag=$2 method=$3 label=$4 traj=$5
  shift 5
  if ! have "$out/$etag.txt"; then
    log "$etag: eval"
    "$DF" eval "$data" "$out/$tag.ply" --trajectory "$traj" --label "$method ($label)" \
      --out "$out/$etag" "$@" > "$out/$etag.log" 2>&1
  fi
  printf '%s\t%s\t%s\t%s\t%s\n' "$method" "$label" "$out/$etag.txt" "$(cat "$out/$tag.seconds")" \
    "$out/$etag.errors.csv" >> "$manifest"
}

tables="$out/tables.md"
{
  echo "<!-- written by tools/eval/run_synthetic.sh -->"
  echo "Run $(date -u +%Y-%m-%dT%H:%MZ) on $(hostname) ($(nproc) cores, load $(cut -d' ' -f1-3 /proc/loadavg)),"
  echo "depthfuse $(git -C "$repo" rev-parse --short HEAD 2>/dev/null || echo '?') ($DF, built $(date -u -r "$DF" +%Y-%m-%dT%H:%MZ)), $("$PY" -c 'import open3d; print("Open3D", open3d.__version__)')."
  echo
} > "$tables"

for scene in $SCENES; do
  case $scene in
    corner) frames=${CORNER_FRAMES:-30} ;;
    room) frames=${ROOM_FRAMES:-40} ;;
    *) frames=${FRAMES:-30} ;;
  esac
  data="$out/$scene"
  if ! have "$data/scene.toml"; then
    log "$scene: synthesising $frames frames (seed $SEED, pose noise $NOISE_M m / $NOISE_DEG deg)"
    rm -rf "$data"
    "$DF" synth "$scene" "$data" --frames "$frames" --seed "$SEED" \
      --pose-noise-m "$NOISE_M" --pose-noise-deg "$NOISE_DEG" > "$out/$scene.synth.log"
  fi
  manifest="$out/$scene.manifest.tsv"
  : > "$manifest"

  for poses in perturbed groundtruth; do
    if [[ $poses == perturbed ]]; then posefile="$data/poses_perturbed.txt"; else posefile="$data/groundtruth.txt"; fi
    for method in full ylimaki17 kyostila13; do
      tag="$scene.$method.$poses"
      run "$tag" "$DF" reconstruct "$data" --poses "$posefile" --method "$method" "${iter_args[@]}" \
        -o "$out/$tag.ply" --trajectory-out "$out/$tag.traj.txt" --report "$out/$tag.reconstruct.txt"
      evaluate "$tag" "$tag.eval" "$method" "$poses" "$out/$tag.traj.txt"
    done
    tag="$scene.open3d.$poses"
    run "$tag" "$PY" "$repo/tools/eval/open3d_tsdf.py" "$data" --poses "$posefile" -o "$out/$tag.ply"
    # Open3D keeps the poses it is given: its ATE is that of the input poses ("before").
    evaluate "$tag" "$tag.eval" "open3d-tsdf 5 mm" "$poses" "$posefile"
  done
  # The clouds of the perturbed poses as given, without the trajectory's alignment.
  for method in ylimaki17 kyostila13 open3d; do
    tag="$scene.$method.perturbed"
    name=$method
    [[ $method == open3d ]] && name="open3d-tsdf 5 mm"
    evaluate "$tag" "$tag.noalign.eval" "$name" "perturbed, not aligned" "$data/poses_perturbed.txt" --no-align
  done

  "$PY" "$repo/tools/eval/collect.py" "$manifest" --svg "$out/$scene.errors.svg" \
    --title "$scene: $frames frames, seed $SEED, perturbed = N(0, $NOISE_M m) per axis, N(0, $NOISE_DEG deg)" \
    > "$out/$scene.md"
  cat "$out/$scene.md" >> "$tables"
  echo "Cumulative error curves: $out/$scene.errors.svg (per cloud: $out/$scene.*.eval.errors.png)" >> "$tables"
  echo >> "$tables"
  cat "$out/$scene.md"
done
log "tables: $tables"
