#!/usr/bin/env bash
# Long-scan memory benchmark (issue 22): a capture daemon publishes the synthetic room at 30 Hz,
# looping, to a fusion daemon with the default memory budget, for M minutes; every minute the fusion
# daemon's resident memory (VmRSS), its fused frame count and rate are printed, read from
# /proc/<pid>/status and from the monitor's status (depthfuse status --json), with the frames the
# daemon received, those it tracked without fusing (behind its camera) and those its queue dropped
# (a checkpoint's cost shows there). Beside them: the share of a core that the capture and the
# fusion daemon each took over the last interval (a synthetic capture renders every frame, on the
# same cores as fusion), the mean time of a fused frame
# (pre-filter, registration and fusion, over about the last ten), and the corrections so far.
#
#   tools/bench/long_scan_rss.sh [--minutes M | --seconds S] [--bin DIR] [--lcm URL] [--frames N]
#                                [--source SOURCE]
#     --minutes M  length of the scan (default 20)
#     --seconds S  a short scan instead, reported at its start and end only (70: two checkpoints;
#                  run it for two builds, alternating, several times: one run says little)
#     --bin DIR    the depthfuse binaries to measure (default: build/bin of this tree)
#     --lcm URL    default: a private loopback port, so a running appliance is not disturbed
#     --frames N   frames of one loop around the room (default 900: 30 s at 30 Hz)
#     --config F   a config file for the fusion daemon (e.g. another memory budget)
#     --source S   the capture's source instead (looped), e.g. a multi-lap walk without pose hints,
#                  so that the pose graph grows: 'synthetic:furnished?frames=1200&hints=0' 
# A benchmark, not a test: it prints figures and leaves the judging to the reader.
set -euo pipefail

here="$(cd "$(dirname "$0")/../.." && pwd)"
minutes=20
seconds=""
bin="$here/build/bin"
lcm_url="udpm://239.255.76.67:7689?ttl=0&recv_buf_size=4194304"
frames=900
source=""
config=()
while [ $# -gt 0 ]; do
  case "$1" in
    --minutes) minutes="$2"; shift 2 ;;
    --seconds) seconds="$2"; shift 2 ;;
    --bin) bin="$2"; shift 2 ;;
    --lcm) lcm_url="$2"; shift 2 ;;
    --frames) frames="$2"; shift 2 ;;
    --source) source="$2"; shift 2 ;;
    --config) config=(--config "$2"); shift 2 ;;
    *) echo "unknown option $1" >&2; exit 2 ;;
  esac
done

[ -n "$source" ] || source="synthetic:room?frames=$frames"
work="$(mktemp -d /tmp/depthfuse-long-scan.XXXXXX)"
pids=()
cleanup() {
  for p in "${pids[@]}"; do kill "$p" 2>/dev/null || true; done
  for p in "${pids[@]}"; do wait "$p" 2>/dev/null || true; done
  rm -rf "$work"
}
trap cleanup EXIT

"$bin/depthfuse-monitor" --lcm "$lcm_url" --key-file "" >"$work/monitor.log" 2>&1 &
pids+=($!)
"$bin/depthfuse-fusion" --lcm "$lcm_url" --key-file "" "${config[@]}" --scan-dir "$work/scans" --autostart long-scan \
  >"$work/fusion.log" 2>&1 &
fusion_pid=$!
pids+=($fusion_pid)
sleep 1
"$bin/depthfuse-capture" --lcm "$lcm_url" --key-file "" --source "$source" --rate 30 --loop \
  >"$work/capture.log" 2>&1 &
capture_pid=$!
pids+=($capture_pid)

rss_mib() { awk '/^VmRSS:/ { printf "%.1f", $2 / 1024 }' "/proc/$1/status"; }
. "$here/tools/bench/proc_common.sh"
# The share of one core, in %, of CPU seconds $1 (now) - $2 (before) over $3 seconds; "-" without
# both.
core_pct() {
  if [ -n "$1" ] && [ -n "$2" ] && [ "$3" -gt 0 ]; then
    awk -v a="$1" -v b="$2" -v s="$3" 'BEGIN { printf "%.0f", 100 * (a - b) / s }'
  else
    echo -
  fi
}
# The fusion daemon's figures (the columns after the CPU shares), from one status of the monitor.
fused() {
  "$bin/depthfuse" status --json --lcm "$lcm_url" --key-file "" --timeout 3 2>/dev/null |
    python3 -c 'import json, sys
s = json.loads(sys.stdin.readline())
d = [d for d in s["daemons"] if d["name"] == "fusion"]
c = d[0].get("counters", {}) if d else {}
print(*[d[0][k] for k in ("frames_out", "output_rate_hz", "point_count", "frames_in", "frames_dropped")],
      *[int(c.get(k, 0)) for k in ("frames_fusion_shed", "keyframes", "loop_closures",
                                    "frames_lost_tracking", "chunks_evicted_total")],
      "%.1f" % c.get("last_correction_mm", 0),
      "%.1f" % sum(c.get(k, 0) for k in ("prefilter_ms_mean", "registration_ms_mean", "fusion_ms_mean")),
      int(c.get("graph_corrections", 0))) if d else print("- - - - - - - - - - - - -")' ||
    echo "- - - - - - - - - - - - -"
}

if [ -n "$seconds" ]; then
  report_s=(0 "$seconds")
  echo "# $bin, $source at 30 Hz (looping) for $seconds s"
else
  report_s=()
  for ((m = 0; m <= minutes; m++)); do report_s+=($((m * 60))); done
  echo "# $bin, $source at 30 Hz (looping) for $minutes min"
fi
echo "# second  fusion_rss_mib  capture_cpu_pct  fusion_cpu_pct  frames_fused  fused_rate_hz  map_points  frames_received  frames_dropped  frames_tracked_only  keyframes  loop_closures  frames_lost_tracking  chunks_evicted  last_correction_mm  fused_frame_ms  corrections"
last=0
capture_cpu_before=""
fusion_cpu_before=""
for t in "${report_s[@]}"; do
  interval=$((t - last))
  sleep $interval
  last=$t
  if ! kill -0 "$fusion_pid" 2>/dev/null; then
    echo "fusion daemon died; its log:" >&2
    tail -20 "$work/fusion.log" >&2
    exit 1
  fi
  capture_cpu=$(cpu_s "$capture_pid" 2>/dev/null || true)
  fusion_cpu=$(cpu_s "$fusion_pid")
  printf '%8d  %14s  %15s  %14s  %s\n' "$t" "$(rss_mib "$fusion_pid")" \
    "$(core_pct "$capture_cpu" "$capture_cpu_before" "$interval")" \
    "$(core_pct "$fusion_cpu" "$fusion_cpu_before" "$interval")" "$(fused)"
  capture_cpu_before=$capture_cpu
  fusion_cpu_before=$fusion_cpu
done
