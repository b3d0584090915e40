#!/usr/bin/env bash
# Issue 35's room-scale table: a furnished room (and a bare one) scanned in handheld laps, without
# poses, through each path the rig runs, against the scene's analytic truth. For each scene:
#
#   true poses   the same frames fused at the true poses: `reconstruct --poses groundtruth.txt
#                --method ylimaki17` (what fusion alone gives when the poses are right)
#   live path    `reconstruct --track --iterations 0` (tracking, each frame fused once)
#   --track      `reconstruct --track` (tracking, then the paper's re-registration rounds)
#   daemons      depthfuse-capture replaying the scene's frames (its folder without the ground
#                truth, so no pose hints) at their recorded 30 Hz into depthfuse-fusion with a
#                scan file and a rig key, stopped when the capture ends, then `depthfuse export`
#                of the scan file (cloud and trajectory). Replayed, not rendered on the fly: the
#                renderer would take the cores the fusion daemon needs, as a Kinect does not
#   Open3D       Open3D 0.16's frame-to-frame point-to-plane ICP (tools/eval/open3d_icp_odometry.py)
#
# then the twin `rooms` scene tracked (`--track --iterations 0`): its ATE, the case where a loop
# closure must be refused. ATE and "% within 5 mm" come from `depthfuse eval` (cloud placed by its
# cameras' rigid alignment to the truth; ATE: positions, TUM's definition); Open3D's ATE from
# tools/eval/ate.py (no cloud). Runs one thing at a time; prints a markdown table per scene with
# the commit, and keeps everything in OUTDIR.
#
#   tools/bench/room_scale.sh [OUTDIR]          (default /tmp/room_scale.$USER)
#
# Environment:
#   FRAMES=1200        frames of each scan (1,200: two laps and back past the start; ~560 a lap)
#   SEED=1             the scenes' seed
#   SCENES="furnished plain"
#   ROOMS_FRAMES=1200  frames of the twin rooms' walk (0: skip it)
#   SKIP=""            rows to leave out: any of truth live track daemons open3d
#   BIN=build/bin      the binaries; PORT=7693 the loopback multicast port (not the appliance's)
#   REUSE=1            keep what OUTDIR already has (a rerun after a failure)
#   FUSION_CONFIG=F    a config file for the daemons' row's fusion daemon (e.g. another
#                      fusion_daemon.memory_budget_mib)
# Needs the multicast route on loopback (tools/lcm/route) and /usr/bin/python3 with Open3D and
# numpy. A benchmark, not a test: it prints figures.
set -euo pipefail

here="$(cd "$(dirname "$0")/../.." && pwd)"
out="${1:-/tmp/room_scale.${USER:-$(id -un)}}"
FRAMES="${FRAMES:-1200}"
SEED="${SEED:-1}"
SCENES="${SCENES:-furnished plain}"
ROOMS_FRAMES="${ROOMS_FRAMES:-1200}"
SKIP="${SKIP:-}"
BIN="${BIN:-$here/build/bin}"
PORT="${PORT:-7693}"
REUSE="${REUSE:-0}"
FUSION_CONFIG="${FUSION_CONFIG:-}"
py=/usr/bin/python3
url="udpm://239.255.76.67:$PORT?ttl=0&recv_buf_size=4194304"
DF="$BIN/depthfuse"
for p in depthfuse depthfuse-capture depthfuse-fusion; do
  [[ -x "$BIN/$p" ]] || { echo "room_scale.sh: no $BIN/$p (build it first)" >&2; exit 2; }
done
mkdir -p "$out"
# shellcheck source=../eval/common.sh
source "$here/tools/eval/common.sh"  # now, elapsed, log, have, run (needs $out, $REUSE)
skipped() { [[ " $SKIP " == *" $1 "* ]]; }

commit="$(git -C "$here" rev-parse --short HEAD 2>/dev/null || echo unknown)"
if [[ -n "$(git -C "$here" status --porcelain --untracked-files=no 2>/dev/null)" ]]; then
  commit="$commit (with local changes)"
fi
t_start=$(now)
echo "load average before: $(cut -d' ' -f1-3 /proc/loadavg)" > "$out/load.txt"

# eval_row TAG FOLDER CLOUD [TRAJECTORY]: "ATE | % within 5 mm" from depthfuse eval.
eval_row() {
  local tag=$1 folder=$2 cloud=$3 traj=${4:-}
  local args=("$folder" "$cloud" --out "$out/$tag.eval" --label "$tag")
  [[ -n $traj ]] && args+=(--trajectory "$traj")
  if ! have "$out/$tag.eval.txt"; then
    "$DF" eval "${args[@]}" > "$out/$tag.eval.log" 2>&1 ||
      { log "$tag: eval failed, see $out/$tag.eval.log"; echo "failed | failed"; return; }
  fi
  local ate within
  ate=$(sed -n 's/.*ATE RMSE: *\([0-9.]*\) mm aligned.*/\1/p' "$out/$tag.eval.txt")
  within=$(sed -n 's/.*; \([0-9.]*\) % within 5 mm.*/\1/p' "$out/$tag.eval.txt")
  echo "${ate:--} | ${within:-?} %"
}

# The tracking counts of a reconstruct log: "N uncertain, L lost, R relocalised".
track_counts() {
  sed -n 's/.*tracked from the first frame: \([0-9]*\) frames uncertain, \([0-9]*\) lost (left out), \([0-9]*\) relocalised.*/\1 uncertain, \2 lost, \3 relocalised/p' "$1"
}

# tracked_row TAG FOLDER LABEL [OPTIONS...]: `reconstruct FOLDER --track OPTIONS`, then its row.
tracked_row() {
  local tag=$1 folder=$2 label=$3
  shift 3
  run "$tag" "$DF" reconstruct "$folder" --track "$@" -o "$out/$tag.ply" \
    --trajectory-out "$out/$tag.traj"
  table_row "$label" "$(eval_row "$tag" "$folder" "$out/$tag.ply" "$out/$tag.traj")" \
    "$(track_counts "$out/$tag.reconstruct.log")" "$tag"
}

# daemons TAG SCENE FOLDER: capture at 30 Hz without hints into the fusion daemon, stop, export.
# Sets daemon_frames.
daemons() {
  local tag=$1 scene=$2 folder=$3 scans="$out/$1.scans" replay="$out/$1.replay" t0
  daemon_frames="?"
  if ! have "$out/$tag.ply"; then
    rm -rf "$scans" "$replay"
    mkdir -p "$replay"
    for f in depth.txt depth rgb.txt rgb camera.toml; do
      [[ -e "$folder/$f" ]] && ln -s "$(cd "$folder" && pwd)/$f" "$replay/$f"
    done
    log "$tag: fusion daemon + capture at 30 Hz, no pose hints"
    # A rig key of its own, as the appliance runs: every frame signed and checked.
    local key="$out/rig.key"
    [[ -s "$key" ]] || (umask 077; od -An -tx1 -N32 /dev/urandom | tr -d ' \n' > "$key")
    t0=$(now)
    local config=()
    [[ -n "$FUSION_CONFIG" ]] && config=(--config "$FUSION_CONFIG")
    "$BIN/depthfuse-fusion" --lcm "$url" --key-file "$key" "${config[@]}" --scan-dir "$scans" --autostart "$scene" \
      > "$out/$tag.fusion.log" 2>&1 &
    local fusion=$!
    sleep 2
    "$BIN/depthfuse-capture" --lcm "$url" --key-file "$key" --name capture \
      --source "tum:$replay" --rate recorded > "$out/$tag.capture.log" 2>&1 ||
      log "$tag: the capture failed, see $out/$tag.capture.log"
    sleep 5  # the frames still queued; then the fusion daemon's heartbeat (its counters)
    "$py" "$here/tools/lcm/watch.py" --lcm "$url" --python-dir "$BIN/../python" \
      --channel DEPTHFUSE_HEARTBEAT --count 3 --timeout 5 > "$out/$tag.heartbeat.jsonl" 2>/dev/null || true
    kill -TERM "$fusion"
    wait "$fusion" || true
    elapsed "$t0" > "$out/$tag.seconds"
    if [[ ! -f "$scans/$scene.dfscan" ]]; then
      log "$tag: no scan file, see $out/$tag.fusion.log"
      return
    fi
    "$DF" export "$scans/$scene.dfscan" -o "$out/$tag.ply" --trajectory "$out/$tag.traj" \
      > "$out/$tag.export.log" 2>&1 || log "$tag: export failed, see $out/$tag.export.log"
  fi
  daemon_frames=$("$py" - "$out/$tag.heartbeat.jsonl" "$out/$tag.capture.log" <<'PY'
import json, re, sys
fusion = None
for line in open(sys.argv[1]):
    m = json.loads(line)["message"]
    if m["name"] == "fusion":
        fusion = m
published = "?"
for line in open(sys.argv[2]):
    g = re.search(r"ended after (\d+) frames", line)
    if g:
        published = g.group(1)
if fusion is None:
    print("published %s, no heartbeat" % published)
else:
    counters = {c["key"]: c["value"] for c in fusion.get("counters", [])}
    print("published %s, received %d, fused %d, tracked only %d, dropped %d, lost %d"
          % (published, fusion["frames_in"], fusion["frames_out"],
             counters.get("frames_fusion_shed", 0), fusion["frames_dropped"],
             fusion["frames_lost"]))
PY
)
}

# table_row LABEL FIGURES FRAMES TAG
declare -a rows
table_row() {
  local seconds="-"
  [[ -s "$out/$4.seconds" ]] && seconds="$(cat "$out/$4.seconds")"
  rows+=("| $1 | $2 | $3 | $seconds |")
}

print_table() {
  echo
  echo "**$1** ($2), commit $commit:"
  echo
  echo "| run | ATE mm | points within 5 mm of the true surface | frames | run s |"
  echo "|---|---:|---:|---|---:|"
  printf '%s\n' "${rows[@]}"
}

tables=()
for scene in $SCENES; do
  data="$out/$scene"
  if ! have "$data/depth.txt"; then
    log "$scene: depthfuse synth $scene --frames $FRAMES --seed $SEED"
    rm -rf "$data"
    "$DF" synth "$scene" "$data" --frames "$FRAMES" --seed "$SEED" > "$out/$scene.synth.log"
  fi
  rows=()
  if ! skipped truth; then
    run "$scene-truth" "$DF" reconstruct "$data" --poses "$data/groundtruth.txt" --method ylimaki17 \
      -o "$out/$scene-truth.ply"
    table_row "the same frames fused at the true poses (\`--method ylimaki17\`)" \
      "$(eval_row "$scene-truth" "$data" "$out/$scene-truth.ply")" \
      "$FRAMES" "$scene-truth"
  fi
  skipped live ||
    tracked_row "$scene-live" "$data" "\`reconstruct --track --iterations 0\` (the live path)" \
      --iterations 0
  skipped track ||
    tracked_row "$scene-track" "$data" "\`reconstruct --track\` (tracking, then the paper's rounds)"
  if ! skipped daemons; then
    daemons "$scene-daemons" "$scene" "$data"
    figures="failed | failed"
    [[ -s "$out/$scene-daemons.ply" ]] &&
      figures="$(eval_row "$scene-daemons" "$data" "$out/$scene-daemons.ply" "$out/$scene-daemons.traj")"
    table_row "daemons: capture at 30 Hz, no pose hints, fusion, export" "$figures" \
      "$daemon_frames" "$scene-daemons"
  fi
  if ! skipped open3d; then
    run "$scene-open3d" "$py" "$here/tools/eval/open3d_icp_odometry.py" "$data" \
      -o "$out/$scene-open3d.traj"
    ate=$("$py" "$here/tools/eval/ate.py" "$out/$scene-open3d.traj" "$data/groundtruth.txt" --json |
            "$py" -c 'import json, sys; print("%.1f" % json.load(sys.stdin)["rmse_mm"])' || echo failed)
    table_row "peer: Open3D 0.16 frame-to-frame point-to-plane ICP" "$ate | -" \
      "$(sed -n 's/.*, \([0-9]*\) frames with fitness < 0.3.*/\1 with fitness < 0.3/p' \
           "$out/$scene-open3d.reconstruct.log")" "$scene-open3d"
  fi
  tables+=("$(print_table "$scene" "$FRAMES frames, seed $SEED, \`depthfuse synth $scene\`")")
done

if ((ROOMS_FRAMES > 0)); then
  data="$out/rooms"
  if ! have "$data/depth.txt"; then
    log "rooms: depthfuse synth rooms --frames $ROOMS_FRAMES --seed $SEED"
    rm -rf "$data"
    "$DF" synth rooms "$data" --frames "$ROOMS_FRAMES" --seed "$SEED" > "$out/rooms.synth.log"
  fi
  rows=()
  tracked_row rooms-live "$data" "\`reconstruct --track --iterations 0\`" --iterations 0
  tables+=("$(print_table "twin rooms" "$ROOMS_FRAMES frames, seed $SEED, \`depthfuse synth rooms\`: 16 rooms alike, where a closure must be refused")")
fi

echo "load average after: $(cut -d' ' -f1-3 /proc/loadavg)" >> "$out/load.txt"
echo
cat "$out/load.txt"
echo "wall time: $(elapsed "$t_start") s; outputs in $out"
printf '%s\n' "${tables[@]}"
