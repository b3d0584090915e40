#!/bin/bash
# Issue 19's live tracking on real data: TUM fr1/xyz replayed by the capture daemon at its recorded
# pace (about 30 Hz, 640x480) over LCM on loopback into the fusion daemon, with no pose hints, as
# a Kinect gives them. The fusion daemon tracks each frame from its constant-velocity prediction,
# drops what it cannot keep up with, and saves its trajectory when stopped. Prints the frames
# published, fused and dropped, the ATE of the daemon's trajectory against groundtruth.txt (nearest
# stamp within 20 ms, best rigid fit: tools/eval/ate.py), its worst pose and how many are over 50
# mm, and the daemon's tracking counts. `tools/bench/track_fr1.sh` is the same sequence through
# the batch loop, every frame fused.
#
#   tools/bench/track_fr1_live.sh [--bin DIR]... [--data DIR] [--work DIR] [--camera FILE]
#                                 [--key-file FILE] [--port P] [--readout yes|no]...
#
# --bin DIR    a directory with depthfuse-capture, depthfuse-fusion (default build/bin); given
#              twice, the first is the baseline, run first, and both are printed side by side
# --data DIR   the TUM folder (default /work/shared/datasets/tum_fr1_xyz)
# --work DIR   where the replay folder, scans and logs go (default /tmp/track_fr1_live.$USER)
# --camera     the camera file (default tools/eval/tum_fr1_camera.toml)
# --key-file   the rig key for both daemons (default: none)
# --port P     the loopback multicast port (default 7699: not the appliance's)
# --readout    whether the fusion daemon is told the camera file's rolling shutter (its
#              row_readout_s, as [sensor] row_readout_s in a config of its own): frames over LCM
#              do not carry it. Default yes; given twice, one for each --bin (a build older than
#              the setting needs no)
#
# The replay folder links the dataset's depth and colour and holds the camera file, but not
# groundtruth.txt: with it the replay would send the true poses as hints. Needs the multicast
# route (tools/lcm/route) and /usr/bin/python3 with numpy.
set -euo pipefail

source "$(dirname "$0")/fr1_common.sh"
camera="$here/tools/eval/tum_fr1_camera.toml"
key_file=""
port=7699
readouts=()
own_option() {
  case "$1" in
    --camera) camera="$2" ;;
    --key-file) key_file="$2" ;;
    --port) port="$2" ;;
    --readout) readouts+=("$2") ;;
    *) return 1 ;;
  esac
}
fr1_parse_args "$@"
fr1_check_inputs depthfuse-capture depthfuse-fusion
[[ -f "$camera" ]] || fr1_die 2 "no camera file $camera"

replay="$work/replay"
rm -rf "$replay"
mkdir -p "$replay"
for f in depth.txt depth rgb.txt rgb; do
  [[ -e "$data/$f" ]] && ln -s "$(cd "$data" && pwd)/$f" "$replay/$f"
done
cp "$camera" "$replay/camera.toml"
readout_s=$(sed -n 's/^row_readout_s *= *\([0-9.eE+-]*\).*/\1/p' "$camera" | tail -1)
printf '[sensor]\nrow_readout_s = %s\n' "${readout_s:-0.0}" > "$work/fusion_readout.toml"
url="udpm://239.255.76.67:$port?ttl=0&recv_buf_size=4194304"

declare -A result
for k in "${!bins[@]}"; do
  b="${bins[$k]}"
  scans="$work/scans_b$k"
  rm -rf "$scans"
  readout="${readouts[$k]:-${readouts[0]:-yes}}"
  [[ $readout == yes || $readout == no ]] || fr1_die 2 "--readout yes|no"
  config=()
  [[ $readout == yes ]] && config=(--config "$work/fusion_readout.toml")
  "$b/depthfuse-fusion" --lcm "$url" --key-file "$key_file" --scan-dir "$scans" "${config[@]}" \
    --autostart fr1 > "$work/fusion_b$k.log" 2>&1 &
  fusion=$!
  sleep 1
  t0=$(date +%s.%N)
  "$b/depthfuse-capture" --lcm "$url" --key-file "$key_file" --source "tum:$replay" \
    --rate recorded > "$work/capture_b$k.log" 2>&1 ||
    { kill $fusion; fr1_die 1 "the capture failed, see $work/capture_b$k.log"; }
  secs=$(echo "$(date +%s.%N) - $t0" | bc)
  sleep 3  # the queue's last frames
  kill -TERM $fusion
  wait $fusion || true
  traj="$scans/fr1-trajectory.txt"
  [[ -f $traj ]] || fr1_die 1 "no $traj, see $work/fusion_b$k.log"
  published=$(sed -n 's/.* ended after \([0-9]*\) frames.*/\1/p' "$work/capture_b$k.log" | tail -1)
  fused=$(grep -vc "^#" "$traj")
  lost=$(grep -c "tracking lost:" "$work/fusion_b$k.log" || true)
  relocalised=$(grep -c "relocalised among the keyframes" "$work/fusion_b$k.log" || true)
  line=$(fr1_ate "$traj" "$data/groundtruth.txt" "$work/b$k.err" "rmse_mm worst_mm over" \
           "%.1f | %.1f | %d")
  result[$k]="$readout | ${published:-?} | $fused | $line | $lost / $relocalised | $(printf %.0f "$secs") s"
  echo "done: $b: published ${published:-?}, fused $fused, ATE $line" >&2
done

fr1_load
echo "| binary | readout | published | fused | ATE RMSE mm | worst mm | > 50 mm | losses / relocalisations | time |"
echo "|---|---|---|---|---|---|---|---|---|"
for k in "${!bins[@]}"; do
  echo "| ${bins[$k]} | ${result[$k]} |"
done
