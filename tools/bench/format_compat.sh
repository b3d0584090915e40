#!/bin/bash
# Do two builds write the same formats? LCM depth frames and scan files, each build reading the
# other's: for a change that must not change a format (the wire, the scan file).
#
#   tools/bench/format_compat.sh BASE_BIN [NEW_BIN (build/bin)] [--keep]
#
# Each build: a synthetic capture recorded with lcm-logger (12 frames), and a fusion daemon
# recording a scan file (colour, keyframes, a checkpoint every 2 s) killed with SIGKILL after 7 s,
# so that the file has checkpointed chunks and poses or frame log records or both. Then every
# depth frame's encoded bytes are compared between the builds, and each build inspects, exports
# and reconstructs the other's files: the outputs must be byte-identical. Exit 0 when all agree.
set -u
ROOT=$(cd "$(dirname "$0")/../.." && pwd)
BASE=${1:?usage: format_compat.sh BASE_BIN [NEW_BIN] [--keep]}
NEW=${2:-$ROOT/build/bin}
KEEP=${3:-}
PY=$ROOT/build/python
W=$(mktemp -d /tmp/depthfuse-format-compat.XXXXXX)
[ "$KEEP" = --keep ] || trap 'rm -rf "$W"' EXIT
mkdir -p "$W/scans"
printf '[lcm]\nkey_file = ""\n[fusion_daemon]\nscan_dir = "%s/scans"\ncheckpoint_interval_s = 2\n' "$W" > "$W/cfg.toml"
status=0

for b in base new; do
  BIN=$BASE; [ $b = new ] && BIN=$NEW
  URL="udpm://239.255.76.67:$((7500 + RANDOM % 50))?ttl=0&recv_buf_size=4194304"
  lcm-logger --lcm-url="$URL" -q "$W/$b.lcmlog" & logger=$!
  sleep 0.5
  "$BIN/depthfuse-capture" --config "$W/cfg.toml" --source "synthetic:corner?frames=12&seed=3" \
    --rate 10 --lcm "$URL" --color none > "$W/$b-capture.txt" 2>&1
  sleep 0.5
  kill $logger; wait $logger 2>/dev/null
  "$BIN/depthfuse-fusion" --config "$W/cfg.toml" --lcm "$URL" --scan-db "$W/$b.dfscan" \
    --autostart c > "$W/$b-fusion.txt" 2>&1 & fusion=$!
  sleep 1
  "$BIN/depthfuse-capture" --config "$W/cfg.toml" --source "synthetic:corner?frames=60&seed=5" \
    --rate 20 --loop --lcm "$URL" --color zstd > /dev/null 2>&1 & capture=$!
  sleep 7
  kill -9 $fusion; kill $capture; wait $fusion $capture 2>/dev/null
done

python3 - "$W" "$PY" <<'EOF' || status=1
import struct, sys
work, py = sys.argv[1], sys.argv[2]
sys.path.insert(0, py)
from depthfuse.depth_frame_t import depth_frame_t

def depth_frames(path):
    data, i, out = open(path, "rb").read(), 0, {}
    while i + 28 <= len(data):
        _, _, _, clen, dlen = struct.unpack(">IqqII", data[i:i + 28])
        i += 28
        channel = data[i:i + clen].decode()
        i += clen
        if channel == "DEPTHFUSE_DEPTH":
            m = depth_frame_t.decode(data[i:i + dlen])
            out[m.sequence] = (m.encoding, bytes(m.data))
        i += dlen
    return out

a, b = depth_frames(work + "/base.lcmlog"), depth_frames(work + "/new.lcmlog")
same = sum(1 for s in a if a[s] == b.get(s))
print("LCM depth frames: base %d, new %d, identical encodings %d" % (len(a), len(b), same))
sys.exit(0 if a and same == len(a) == len(b) else 1)
EOF

for f in base new; do
  for b in base new; do
    BIN=$BASE; [ $b = new ] && BIN=$NEW
    copy="$W/scans/$f-read-by-$b.dfscan"  # each reader on its own copy: export folds the log in
    cp "$W/$f.dfscan" "$copy"
    [ -f "$W/$f.dfscan-wal" ] && cp "$W/$f.dfscan-wal" "$copy-wal"
    if ! "$BIN/depthfuse" inspect "$copy" > "$W/inspect-$f-by-$b.txt" 2>&1; then
      echo "scan file by $f: inspect by $b FAILED ($W/inspect-$f-by-$b.txt)"; status=1
    fi
    "$BIN/depthfuse" export "$copy" -o "$W/$f-export-by-$b.ply" > /dev/null 2>&1 || status=1
    "$BIN/depthfuse" reconstruct "$W/$f.lcmlog" -o "$W/$f-lcm-by-$b.ply" > /dev/null 2>&1 || status=1
  done
  echo "scan file by $f: $(grep -E '^frame log|integrity' "$W/inspect-$f-by-new.txt" | tr -s ' ' | tr '\n' ' ')"
  for what in export lcm; do
    if cmp -s "$W/$f-$what-by-base.ply" "$W/$f-$what-by-new.ply"; then
      echo "  $what of the $f build's file: byte-identical from both builds ($(stat -c %s "$W/$f-$what-by-base.ply") bytes)"
    else
      echo "  $what of the $f build's file: the builds DIFFER"; status=1
    fi
  done
done
[ "$KEEP" = --keep ] && echo "files kept in $W"
exit $status
