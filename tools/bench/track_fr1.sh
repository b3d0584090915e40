#!/bin/bash
# Issue 19's tracking benchmark on TUM fr1/xyz: every frame, every 3rd and every 5th, each tracked
# from the first frame without poses (`reconstruct DIR --track --method full --iterations 0`), one
# run at a time. Prints per run the ATE (positions against groundtruth.txt, nearest stamp within
# 20 ms, after the best rigid fit: tools/eval/ate.py), the worst pose, how many are over 50 mm, and
# the tracker's own counts (uncertain / lost / relocalised).
#
#   tools/bench/track_fr1.sh [--bin DIR]... [--data DIR] [--work DIR] [--strides "1 3 5"]
#                            [--max-frames N] [--config FILE] [--camera FILE]...
#
# --bin DIR    a directory with `depthfuse` (default build/bin); given twice, the first is the
#              baseline and both are printed side by side
# --data DIR   the TUM folder (default /work/shared/datasets/tum_fr1_xyz)
# --work DIR   where the subsets, clouds and trajectories go (default /tmp/track_fr1.$USER)
# --strides    which subsets to run (1: every frame)
# --max-frames at most this many frames of each subset (quick looks; the targets are on all)
# --config     a config file passed to reconstruct (default: the built-in defaults)
# --camera     the camera file (default tools/eval/tum_fr1_camera.toml); given twice, one for each
#              --bin (the same DIR may be given twice to compare two camera files)
#
# The subsets are made by tools/eval/tum_subset.py (every n-th depth frame with a ground-truth pose
# within 20 ms); stride 1 is the dataset itself unless --max-frames is given. Needs /usr/bin/python3
# with numpy (the python3 on PATH may lack it).
set -euo pipefail

source "$(dirname "$0")/fr1_common.sh"
strides="1 3 5"
max_frames=""
config=""
cameras=()
own_option() {
  case "$1" in
    --strides) strides="$2" ;;
    --max-frames) max_frames="$2" ;;
    --config) config="$2" ;;
    --camera) cameras+=("$2") ;;
    *) return 1 ;;
  esac
}
fr1_parse_args "$@"
fr1_check_inputs depthfuse
[[ ${#cameras[@]} -eq 0 ]] && cameras=("$here/tools/eval/tum_fr1_camera.toml")
[[ ${#cameras[@]} -gt 2 || (${#cameras[@]} -eq 2 && ${#bins[@]} -ne 2) ]] &&
  fr1_die 2 "--camera once, or twice with two --bin"
mkdir -p "$work"

subset() {  # stride -> folder
  local s=$1
  if [[ $s == 1 && -z $max_frames ]]; then echo "$data"; return; fi
  local dir="$work/fr1_s${s}${max_frames:+_n$max_frames}"
  if [[ ! -f $dir/depth.txt ]]; then
    "$py" "$here/tools/eval/tum_subset.py" "$data" "$dir" --stride "$s" \
      ${max_frames:+--max-frames "$max_frames"} >&2
  fi
  echo "$dir"
}

declare -A result
for s in $strides; do
  dir=$(subset "$s")
  for k in "${!bins[@]}"; do
    b="${bins[$k]}"
    camera="${cameras[$k]:-${cameras[0]}}"
    tag="s${s}_b${k}"
    log="$work/$tag.log"
    t0=$(date +%s.%N)
    "$b/depthfuse" reconstruct "$dir" --track --method full --iterations 0 --camera "$camera" \
      ${config:+--config "$config"} -o "$work/$tag.ply" --trajectory-out "$work/$tag.traj" \
      > "$log" 2>&1 || fr1_die 1 "$b/depthfuse failed, see $log"
    secs=$(echo "$(date +%s.%N) - $t0" | bc)
    counts=$(sed -n 's/.*tracked from the first frame: \([0-9]*\) frames uncertain, \([0-9]*\) lost (left out), \([0-9]*\) relocalised.*/\1 \/ \2 \/ \3/p' "$log")
    line=$(fr1_ate "$work/$tag.traj" "$dir/groundtruth.txt" "$work/$tag.err" \
             "rmse_mm worst_mm worst_index over pairs" "%.1f | %.1f (pose %d) | %d | %d")
    result[$tag]="$line | ${counts:-?} | $(printf %.0f "$secs") s"
    echo "done: stride $s, $b: $line; uncertain/lost/relocalised ${counts:-?}" >&2
  done
done

fr1_load
echo "| frames | binary | ATE RMSE mm | worst mm | > 50 mm | poses | uncertain / lost / relocalised | time |"
echo "|---|---|---|---|---|---|---|---|"
for s in $strides; do
  name="every frame"; [[ $s != 1 ]] && name="every ${s}th"; [[ $s == 3 ]] && name="every 3rd"
  [[ -n $max_frames ]] && name="$name (first $max_frames)"
  for k in "${!bins[@]}"; do
    what="${bins[$k]}"; [[ ${#cameras[@]} -eq 2 ]] && what="$what, $(basename "${cameras[$k]}")"
    echo "| $name | $what | ${result[s${s}_b${k}]} |"
  done
done
