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

here="$(cd "$(dirname "$0")/../.." && pwd)"
py=/usr/bin/python3
bins=()
data=/work/shared/datasets/tum_fr1_xyz
work="/tmp/track_fr1_live.${USER:-$(id -un)}"
camera="$here/tools/eval/tum_fr1_camera.toml"
key_file=""
port=7699
readouts=()
while [[ $# -gt 0 ]]; do
  case "$1" in
    --bin) bins+=("$2"); shift 2 ;;
    --data) data="$2"; shift 2 ;;
    --work) work="$2"; shift 2 ;;
    --camera) camera="$2"; shift 2 ;;
    --key-file) key_file="$2"; shift 2 ;;
    --port) port="$2"; shift 2 ;;
    --readout) readouts+=("$2"); shift 2 ;;
    -h|--help) sed -n '2,25p' "$0" | sed 's/^# \{0,1\}//'; exit 0 ;;
    *) echo "track_fr1_live.sh: unknown argument $1 (--help)" >&2; exit 2 ;;
  esac
done
[[ ${#bins[@]} -eq 0 ]] && bins=("$here/build/bin")
[[ ${#bins[@]} -gt 2 ]] && { echo "track_fr1_live.sh: at most two --bin" >&2; exit 2; }
for b in "${bins[@]}"; do
  for p in depthfuse-capture depthfuse-fusion; do
    [[ -x "$b/$p" ]] || { echo "track_fr1_live.sh: no $b/$p" >&2; exit 2; }
  done
done
[[ -f "$data/depth.txt" && -f "$data/groundtruth.txt" ]] || {
  echo "track_fr1_live.sh: $data has no depth.txt and groundtruth.txt" >&2; exit 2; }
[[ -f "$camera" ]] || { echo "track_fr1_live.sh: no camera file $camera" >&2; exit 2; }

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
  [[ $readout == yes || $readout == no ]] || { echo "track_fr1_live.sh: --readout yes|no" >&2; exit 2; }
  config=()
  [[ $readout == yes ]] && config=(--config "$work/fusion_readout.toml")
  "$b/depthfuse-fusion" --lcm "$url" --key-file "$key_file" --scan-dir "$scans" "${config[@]}" \
    --autostart fr1 > "$work/fusion_b$k.log" 2>&1 &
  fusion=$!
  sleep 1
  t0=$(date +%s.%N)
  "$b/depthfuse-capture" --lcm "$url" --key-file "$key_file" --source "tum:$replay" \
    --rate recorded > "$work/capture_b$k.log" 2>&1 ||
    { echo "track_fr1_live.sh: the capture failed, see $work/capture_b$k.log" >&2; kill $fusion; exit 1; }
  secs=$(echo "$(date +%s.%N) - $t0" | bc)
  sleep 3  # the queue's last frames
  kill -TERM $fusion
  wait $fusion || true
  traj="$scans/fr1-trajectory.txt"
  [[ -f $traj ]] || { echo "track_fr1_live.sh: no $traj, see $work/fusion_b$k.log" >&2; exit 1; }
  published=$(sed -n 's/.* ended after \([0-9]*\) frames.*/\1/p' "$work/capture_b$k.log" | tail -1)
  fused=$(grep -vc "^#" "$traj")
  lost=$(grep -c "tracking lost:" "$work/fusion_b$k.log" || true)
  relocalised=$(grep -c "relocalised among the keyframes" "$work/fusion_b$k.log" || true)
  ate=$("$py" "$here/tools/eval/ate.py" "$traj" "$data/groundtruth.txt" --json \
          --per-frame "$work/b$k.err")
  line=$("$py" -c 'import json,sys; a=json.loads(sys.argv[1]); print("%.1f | %.1f | %d" % (a["rmse_mm"], a["worst_mm"], a["over"]))' "$ate")
  result[$k]="$readout | ${published:-?} | $fused | $line | $lost / $relocalised | $(printf %.0f "$secs") s"
  echo "done: $b: published ${published:-?}, fused $fused, ATE $line" >&2
done

echo "load: $(cut -d' ' -f1-3 /proc/loadavg)"
echo
echo "| binary | readout | published | fused | ATE RMSE mm | worst mm | > 50 mm | losses / relocalisations | time |"
echo "|---|---|---|---|---|---|---|---|---|"
for k in "${!bins[@]}"; do
  echo "| ${bins[$k]} | ${result[$k]} |"
done
