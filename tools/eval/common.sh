# Helpers shared by run_synthetic.sh and run_tum.sh (sourced, not run). They expect $out (the output
# folder) and $REUSE (1 = keep what is already in $out).

now() { date +%s.%N; }
elapsed() { awk -v a="$1" -v b="$(now)" 'BEGIN { printf "%.0f", b - a }'; }
log() { echo "[$(date +%H:%M:%S)] $*" >&2; }
have() { [[ $REUSE == 1 && -s "$1" ]]; }

# run TAG CMD...: runs a reconstruction once (or reuses it), its wall time in TAG.seconds.
run() {
  local tag=$1 t0
  shift
  if have "$out/$tag.seconds"; then log "$tag: reused"; return; fi
  log "$tag: reconstruct"
  t0=$(now)
  "$@" > "$out/$tag.reconstruct.log" 2>&1
  elapsed "$t0" > "$out/$tag.seconds"
}
