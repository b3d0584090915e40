#!/usr/bin/env bash
# Frames the fusion daemon's queue drops on a large scene: the synthetic room (~890 k points) at
# 30 Hz with pose hints, for S seconds (two 30 s checkpoints in the default 70), and the daemon's
# counters at the end, from the monitor's status. Run it for two builds, alternating, several times:
# a checkpoint's cost shows as drops, and one run says little on a shared machine.
#
#   tools/bench/room_drops.sh [--bin DIR] [--seconds S] [--port P]
# A benchmark, not a test: it prints figures and leaves the judging to the reader.
set -euo pipefail

here="$(cd "$(dirname "$0")/../.." && pwd)"
bin="$here/build/bin"
seconds=70
port=7715
while [ $# -gt 0 ]; do
  case "$1" in
    --bin) bin="$2"; shift 2 ;;
    --seconds) seconds="$2"; shift 2 ;;
    --port) port="$2"; shift 2 ;;
    *) echo "unknown option $1" >&2; exit 2 ;;
  esac
done
lcm="udpm://239.255.76.67:$port?ttl=0&recv_buf_size=4194304"
work="$(mktemp -d /tmp/depthfuse-room-drops.XXXXXX)"
pids=()
cleanup() {
  for p in "${pids[@]}"; do kill "$p" 2>/dev/null || true; done
  for p in "${pids[@]}"; do wait "$p" 2>/dev/null || true; done
  rm -rf "$work"
}
trap cleanup EXIT

"$bin/depthfuse-monitor" --lcm "$lcm" --key-file "" >"$work/monitor.log" 2>&1 &
pids+=($!)
"$bin/depthfuse-fusion" --lcm "$lcm" --key-file "" --scan-dir "$work/scans" --autostart room \
  >"$work/fusion.log" 2>&1 &
pids+=($!)
sleep 1
"$bin/depthfuse-capture" --lcm "$lcm" --key-file "" --source "synthetic:room?frames=900" --rate 30 \
  --loop >"$work/capture.log" 2>&1 &
pids+=($!)
sleep "$seconds"
echo "# $bin, synthetic:room?frames=900 at 30 Hz with hints, $seconds s"
"$bin/depthfuse" status --json --lcm "$lcm" --key-file "" --timeout 3 |
  python3 -c 'import json, sys
s = json.loads(sys.stdin.readline())
d = [d for d in s["daemons"] if d["name"] == "fusion"]
if not d:
    sys.exit("no status from the fusion daemon")
d = d[0]
print("received %d  fused %d  dropped by the queue %d  lost in transport %d" % (
    d["frames_in"], d["frames_out"], d["frames_dropped"], d["frames_lost"]))'
