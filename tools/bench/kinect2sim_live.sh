#!/usr/bin/env bash
# The simulated Kinect V2 into the fusion daemon, beside a TUM replay, one after the other on the
# same machine (issue 20): for each source a fusion daemon (--autostart, default config) and a
# capture daemon publishing at 30 Hz, looping, for SECS seconds; then the heartbeats' figures.
#
#   tools/bench/kinect2sim_live.sh [--secs S] [--bin DIR] [--tum DIR] [--sim SPEC] [--config F]
#     --secs S    seconds per source (default 40)
#     --bin DIR   the depthfuse binaries (default: build/bin of this tree)
#     --tum DIR   a TUM folder in our layout (default /tmp/fr1gt, see tools/eval/tum_subset.py)
#     --sim SPEC  the simulated sensor (default kinect2sim:room?frames=900)
#     --config F  a config for both daemons (e.g. capture.kinect2_decoder_threads = 2)
# Prints per source: frames published by the capture and its rate, the capture's CPU time per
# frame, kinect2sim's own times per frame (decoding, the whole driver path, rendering and
# encoding in its producer thread), and the fusion daemon's frames received, fused, dropped, its
# output rate and fusion/registration times. A benchmark, not a test: it prints figures.
set -euo pipefail

here="$(cd "$(dirname "$0")/../.." && pwd)"
secs=40
bin="$here/build/bin"
tum=/tmp/fr1gt
sim="kinect2sim:room?frames=900"
config=""
lcm_url="udpm://239.255.76.67:7691?ttl=0&recv_buf_size=4194304"
while [ $# -gt 0 ]; do
  case "$1" in
    --secs) secs="$2"; shift 2 ;;
    --bin) bin="$2"; shift 2 ;;
    --tum) tum="$2"; shift 2 ;;
    --sim) sim="$2"; shift 2 ;;
    --config) config="$2"; shift 2 ;;
    *) echo "unknown option $1" >&2; exit 2 ;;
  esac
done
config_args=()
[ -n "$config" ] && config_args=(--config "$config")

work="$(mktemp -d /tmp/depthfuse-k2sim-live.XXXXXX)"
pids=()
cleanup() {
  for p in "${pids[@]}"; do kill "$p" 2>/dev/null || true; done
  for p in "${pids[@]}"; do wait "$p" 2>/dev/null || true; done
  rm -rf "$work"
}
trap cleanup EXIT

. "$here/tools/bench/proc_common.sh"

run() {
  local tag="$1" source="$2"
  "$bin/depthfuse-fusion" --lcm "$lcm_url" --key-file "" "${config_args[@]}" --scan-dir "$work/scans-$tag" \
    --autostart "$tag" >"$work/fusion-$tag.log" 2>&1 &
  local fusion=$!; pids+=($fusion)
  sleep 2
  "$bin/depthfuse-capture" --lcm "$lcm_url" --key-file "" "${config_args[@]}" --source "$source" --rate 30 \
    --loop --name capture >"$work/capture-$tag.log" 2>&1 &
  local capture=$!; pids+=($capture)
  sleep "$secs"
  local capture_cpu; capture_cpu="$(cpu_s "$capture")"
  python3 "$here/tools/lcm/watch.py" --lcm "$lcm_url" --python-dir "$bin/../python" \
    --channel DEPTHFUSE_HEARTBEAT --count 8 --timeout 5 >"$work/hb-$tag.jsonl" || true
  kill "$capture" "$fusion"; wait "$capture" "$fusion" 2>/dev/null || true
  python3 - "$work/hb-$tag.jsonl" "$tag" "$source" "$capture_cpu" <<'PY'
import json, sys
path, tag, source, capture_cpu = sys.argv[1], sys.argv[2], sys.argv[3], float(sys.argv[4])
last = {}
for line in open(path):
    m = json.loads(line)["message"]
    last[m["name"]] = m
def counters(m):
    return {kv["key"]: kv["value"] for kv in m["counters"]}
print("%s (%s)" % (tag, source))
c = last.get("capture")
if c:
    cc = counters(c)
    out = max(1, c["frames_out"])
    print("  capture: %d frames published, %.1f Hz, %.1f ms CPU per frame (whole process)"
          % (c["frames_out"], c["output_rate_hz"], 1000.0 * capture_cpu / out))
    if "kinect2sim_frames" in cc:
        print("  kinect2sim per frame: decode %.1f ms, driver path %.1f ms (decode + registration"
              " + metres), producer: render %.1f ms, encode %.1f ms; %d dropped packets"
              % (cc["kinect2sim_decode_ms_mean"], cc["kinect2sim_driver_ms_mean"],
                 cc["kinect2sim_render_ms_mean"], cc["kinect2sim_encode_ms_mean"],
                 cc["kinect2sim_dropped_packets"]))
f = last.get("fusion")
if f:
    fc = counters(f)
    received = max(1, f["frames_in"])
    print("  fusion: %d received, %d fused (%.1f Hz), %d dropped (%.1f %%), %d lost, fusion %.1f ms,"
          " registration %.1f ms per frame"
          % (f["frames_in"], f["frames_out"], f["output_rate_hz"], f["frames_dropped"],
             100.0 * f["frames_dropped"] / received, f["frames_lost"], fc.get("fusion_ms_mean", 0),
             fc.get("registration_ms_mean", 0)))
if not c or not f:
    print("  (missing heartbeats: see the daemons' logs)")
PY
}

echo "load average before: $(cut -d' ' -f1-3 /proc/loadavg)"
run sim "$sim"
run tum "tum:$tum"
echo "load average after: $(cut -d' ' -f1-3 /proc/loadavg)"
