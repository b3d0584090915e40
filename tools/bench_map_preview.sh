#!/bin/bash
# The map preview's figures (docs/results.md): the fusion daemon with synthetic:room captured at
# 30 Hz for SECS seconds (40), map_preview.enabled on, then off, one after the other; prints the
# fusion heartbeat's rates and times and the preview's counters. Run from the source tree:
#   tools/bench_map_preview.sh
BUILD=${BUILD:-build}; B=$BUILD/bin; W=$(mktemp -d)
URL="udpm://239.255.76.67:7793?ttl=0&recv_buf_size=4194304"
for preview in true false; do
  printf '[map_preview]\nenabled = %s\n' $preview > $W/cfg-$preview.toml
  $B/depthfuse-fusion --lcm "$URL" --key-file "" --config $W/cfg-$preview.toml --scan-dir $W/scans-$preview --autostart p$preview > $W/fus-$preview.log 2>&1 & F=$!
  sleep 1
  $B/depthfuse-capture --lcm "$URL" --key-file "" --source synthetic:room --rate 30 --loop > $W/cap-$preview.log 2>&1 & C=$!
  sleep ${SECS:-40}
  python3 tools/lcm/watch.py --lcm "$URL" --python-dir $BUILD/python --channel DEPTHFUSE_HEARTBEAT --count 6 --timeout 5 > $W/hb-$preview.jsonl
  kill $C; kill $F; wait $F
  python3 - $W/hb-$preview.jsonl $preview <<'PY'
import json,sys
for line in open(sys.argv[1]):
    m=json.loads(line)["message"]
    if m["name"]!="fusion": continue
    c={kv["key"]:kv["value"] for kv in m["counters"]}
    fo=m["frames_out"]
    print("preview=%s frames_in=%d fused=%d dropped=%d out_hz=%.1f fusion_ms=%.1f registration_ms=%.1f points=%d" % (sys.argv[2], m["frames_in"], fo, m["frames_dropped"], m["output_rate_hz"], c["fusion_ms_mean"], c["registration_ms_mean"], m["point_count"]))
    if sys.argv[2] == "true":
        print("  preview: %.0f B/s now, %.0f B total, %d msgs, pending %d, per delta %.1f ms mean %.1f ms max, %.2f ms per fused frame" % (c["map_preview_bytes_per_s"], c["map_preview_bytes"], c["map_preview_messages"], c["map_preview_chunks_pending"], c["map_preview_ms_mean"], c["map_preview_ms_max"], c["map_preview_ms_total"]/max(1,fo)))
    break
PY
done
