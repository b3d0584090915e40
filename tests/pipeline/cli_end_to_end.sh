#!/usr/bin/env bash
# The CLI as a user runs it: synth -> reconstruct -> eval on a tiny scan, and bad input that must
# end in a clear message and a non-zero exit (never a crash: exit codes >= 128 are signals).
set -u
DF="$1"
T=$(mktemp -d)
trap 'rm -rf "$T"' EXIT
fails=0
passes=0
check() {  # check <name> <expected exit: 0|nonzero|N> <grep pattern for output> <command...>
  local name="$1" want="$2" pattern="$3"; shift 3
  "$@" >"$T/out" 2>&1
  local rc=$?
  if [[ $rc -ge 128 ]]; then echo "FAIL $name: crashed with signal $((rc - 128))"; cat "$T/out"; fails=$((fails+1)); return; fi
  if [[ $want == 0 && $rc != 0 ]] || [[ $want != 0 && $rc == 0 ]] || [[ $want =~ ^[0-9]+$ && $rc != "$want" ]]; then
    echo "FAIL $name: exit $rc"; cat "$T/out"; fails=$((fails+1)); return
  fi
  if ! grep -q -- "$pattern" "$T/out"; then echo "FAIL $name: output lacks '$pattern'"; cat "$T/out"; fails=$((fails+1)); return; fi
  echo "ok   $name"; passes=$((passes+1))
}
lacks() {  # lacks <name> <grep pattern the output must not have> <command...>: exits 0 without it
  local name="$1" pattern="$2"; shift 2
  "$@" >"$T/out" 2>&1
  local rc=$?
  if [[ $rc != 0 ]] || grep -q -- "$pattern" "$T/out"; then
    echo "FAIL $name: exit $rc, or the output has '$pattern'"; cat "$T/out"; fails=$((fails+1)); return
  fi
  echo "ok   $name"; passes=$((passes+1))
}

check synth 0 "wrote 6 frames" "$DF" synth corner "$T/c" --frames 6 --pose-noise-m 0.01 --pose-noise-deg 0.5
check reconstruct 0 "points:" "$DF" reconstruct "$T/c" --poses "$T/c/poses_perturbed.txt" --iterations 2 -o "$T/c.ply" --trajectory-out "$T/c.txt" --report "$T/report.txt"
check ply-written 0 "element vertex" head -c 400 "$T/c.ply"
check report-written 0 "method:       full" cat "$T/report.txt"
check eval 0 "jaccard index" "$DF" eval "$T/c" "$T/c.ply" --trajectory "$T/c.txt"
check eval-png 0 "PNG" file "$T/c.eval.errors.png"

# Bad input.
cp -r "$T/c" "$T/bad"
first=$(ls "$T/bad/depth" | head -1)
printf 'not a png at all' > "$T/bad/depth/$first"
check corrupt-png nonzero "cannot decode" "$DF" reconstruct "$T/bad" -o "$T/x.ply"
cp -r "$T/c" "$T/missing"; rm "$T/missing/depth/$(ls "$T/missing/depth" | tail -1)"
check missing-png nonzero "missing image" "$DF" reconstruct "$T/missing" -o "$T/x.ply"
printf '0.0 nan 0 0 0 0 0 1\n' > "$T/nan.txt"
check nan-trajectory nonzero "field 2 is nan" "$DF" reconstruct "$T/c" --poses "$T/nan.txt" -o "$T/x.ply"
printf 'garbage\n' > "$T/garbage.txt"
check garbage-trajectory nonzero "is not a number" "$DF" reconstruct "$T/c" --poses "$T/garbage.txt" -o "$T/x.ply"
printf '100.0 0 0 0 0 0 0 1\n' > "$T/far.txt"
check frame-without-pose nonzero "has no pose" "$DF" reconstruct "$T/c" --poses "$T/far.txt" -o "$T/x.ply"
cp -r "$T/c" "$T/empty"; printf '# nothing\n' > "$T/empty/depth.txt"
check empty-sequence nonzero "empty sequence" "$DF" reconstruct "$T/empty" -o "$T/x.ply"
cp -r "$T/c" "$T/size"; sed -i 's/^width = 512/width = 640/' "$T/size/camera.toml"
check wrong-size nonzero "512x424 but the camera is 640x424" "$DF" reconstruct "$T/size" -o "$T/x.ply"
# A first frame with no depth, or none in the sensor's range, cannot start tracking; colour of
# another size than the depth is used without (python3's standard library writes the PNGs).
png() {  # png <file> <width> <height> <bit depth 16: one channel | 8: RGB> <sample value>
  python3 -c '
import struct, sys, zlib
f, w, h, bits, value = sys.argv[1], int(sys.argv[2]), int(sys.argv[3]), int(sys.argv[4]), int(sys.argv[5])
row = b"\0" + (struct.pack(">H", value) * w if bits == 16 else bytes([value]) * 3 * w)
chunk = lambda t, d: struct.pack(">I", len(d)) + t + d + struct.pack(">I", zlib.crc32(t + d))
ihdr = struct.pack(">IIBBBBB", w, h, bits, 0 if bits == 16 else 2, 0, 0, 0)
open(f, "wb").write(b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", ihdr) + chunk(b"IDAT", zlib.compress(row * h)) + chunk(b"IEND", b""))
' "$@"
}
for case in "0 all 0 (no measurement)" "65535 outside the sensor's range"; do
  cp -r "$T/c" "$T/first"; png "$T/first/depth/$first" 512 424 16 "${case%% *}"
  check "first-frame-${case%% *}" nonzero "frame 0: no valid depth measurement: 217088 pixels, .*${case#* }" \
    "$DF" reconstruct "$T/first" --track -o "$T/x.ply"
  rm -rf "$T/first"
done
cp -r "$T/c" "$T/rgb"; png "$T/rgb/rgb/$(ls "$T/rgb/rgb" | head -1)" 120 100 8 90
check colour-wrong-size 0 "rgb/.* is 120x100, its depth 512x424: colour must be registered" \
  "$DF" reconstruct "$T/rgb" --track --iterations 0 -o "$T/x.ply"
# Every subcommand starts as every program does (lib/daemon's Startup): --log-level is taken and
# applied (the colour warning above is the TUM reader's, category Tum), and a level that is not one
# is refused by name with the usage (exit 2) before anything is read.
check log-level-debug 0 "colour must be registered" \
  "$DF" reconstruct "$T/rgb" --track --iterations 0 -o "$T/x.ply" --log-level debug
lacks log-level-applied "colour must be registered" \
  "$DF" reconstruct "$T/rgb" --track --iterations 0 -o "$T/x.ply" --log-level Tum=error
check synth-log-level 0 "wrote 2 frames" "$DF" synth corner "$T/l" --frames 2 --log-level debug
check eval-log-level 0 "jaccard index" "$DF" eval "$T/c" "$T/c.ply" --out "$T/l" --log-level debug
for cmd in inspect "export -o $T/x.ply" refine; do  # taken: what fails is the missing file
  check "${cmd%% *}-log-level" nonzero "$T/none.dfscan: no such scan file" \
    "$DF" $cmd "$T/none.dfscan" --log-level debug
done
for cmd in reconstruct export eval inspect refine synth status scan; do
  check "$cmd-bad-log-level" 2 "depthfuse $cmd: --log-level: log level 'loud' is not one of" \
    "$DF" $cmd --log-level loud
done
check offline-without-bus 2 "depthfuse synth: unknown option --lcm" "$DF" synth corner "$T/l" --lcm udpm://
check no-such-folder nonzero "no such folder" "$DF" reconstruct "$T/nope" -o "$T/x.ply"
check bad-method nonzero "--method must be" "$DF" reconstruct "$T/c" --method best -o "$T/x.ply"
check bad-iterations nonzero "expects an integer" "$DF" reconstruct "$T/c" --iterations many -o "$T/x.ply"
check huge-iterations nonzero "expects an integer in \[0, 1000\]" "$DF" reconstruct "$T/c" --iterations 2147483648 -o "$T/x.ply"
for bad in 'fx = 1e-300' 'depth_scale = 1e-300' 'cx = -1e30'; do
  cp -r "$T/c" "$T/cam"; printf '%s\n' "$bad" >> "$T/cam/camera.toml"
  sed -i "0,/^${bad%% *} = .*/{/^${bad%% *} = .*/d}" "$T/cam/camera.toml"
  check "camera-${bad%% *}" nonzero "camera.${bad%% *}" "$DF" reconstruct "$T/cam" -o "$T/x.ply"
  rm -rf "$T/cam"
done
# A sequence far longer than memory: the batch method, which holds every frame for its
# re-registration rounds, refuses it up front with the figure; without rounds the frames stream
# through in bounded memory. The limit is on address space, not memory: the libraries' mappings take
# ~450 MB of it (ATLAS, the BLAS that Ceres's package brings, takes ~100 MB), and holding 200
# frames takes more than the 600 MB allowed here.
check huge-sequence-held nonzero "holds every frame in memory: 100000000 frames" bash -c "ulimit -v 4000000; '$DF' reconstruct 'synthetic:corner?frames=100000000' -o '$T/x.ply'"
check huge-sequence-streamed 0 "frames:       200" bash -c "ulimit -v 600000; '$DF' reconstruct 'synthetic:corner?frames=100000000' --iterations 0 --max-frames 200 -o '$T/x.ply'"
printf 'ply\nformat binary_little_endian 1.0\nelement vertex 4000000000\nproperty float x\nproperty float y\nproperty float z\nend_header\n' > "$T/huge.ply"
check ply-claims-4e9-vertices nonzero "declares 4000000000 vertices" "$DF" eval "$T/c" "$T/huge.ply"
printf 'this is = = not toml\n' > "$T/bad.toml"
check garbage-config nonzero "bad.toml" "$DF" reconstruct "$T/c" --config "$T/bad.toml" -o "$T/x.ply"
check truncated-ply nonzero "truncated" bash -c "head -c 2000 '$T/c.ply' > '$T/t.ply' && '$DF' eval '$T/c' '$T/t.ply'"
# Inputs that are not regular files (issue 36: a FIFO given as a scan file or an image made inspect,
# export and reconstruct hang): each is refused, by name, before anything opens it for reading. A
# hang would end in timeout's exit 124 without the message.
mkfifo "$T/fifo"
fifo_check() {  # fifo_check <name> <what is refused> <path refused> <command...>
  local name="$1" what="$2" refused="$3"; shift 3
  check "$name" nonzero "$what $refused is a FIFO, not a regular file" timeout 30 "$@"
}
fifo_check fifo-scan-inspect "scan file" "$T/fifo" "$DF" inspect "$T/fifo"
fifo_check fifo-scan-export "scan file" "$T/fifo" "$DF" export "$T/fifo" -o "$T/x.ply"
fifo_check fifo-poses "trajectory" "$T/fifo" "$DF" reconstruct "$T/c" --poses "$T/fifo" -o "$T/x.ply"
fifo_check fifo-config "config" "$T/fifo" "$DF" reconstruct "$T/c" --config "$T/fifo" -o "$T/x.ply"
fifo_check fifo-cloud "cloud" "$T/fifo" "$DF" eval "$T/c" "$T/fifo"
fifo_check fifo-lcm-log "LCM log" "$T/fifo" "$DF" reconstruct "$T/fifo" -o "$T/x.ply"
for file in camera.toml depth.txt "depth/$first" "rgb/$(ls "$T/c/rgb" | head -1)"; do
  cp -r "$T/c" "$T/f"; rm "$T/f/$file"; mkfifo "$T/f/$file"
  case "$file" in camera.toml) what="camera file" ;; depth.txt) what="list" ;; *) what="image" ;; esac
  fifo_check "fifo-$file" "$what" "$T/f/$file" "$DF" reconstruct "$T/f" --track --iterations 0 -o "$T/x.ply"
  rm -rf "$T/f"
done
check dir-as-scan nonzero "scan file $T/c is a directory, not a regular file" timeout 30 "$DF" inspect "$T/c"
check device-as-poses nonzero "trajectory /dev/zero is a character device, not a regular file" \
  timeout 30 "$DF" reconstruct "$T/c" --poses /dev/zero -o "$T/x.ply"

echo "cli: $passes passed, $fails failed"
exit $((fails > 0))
