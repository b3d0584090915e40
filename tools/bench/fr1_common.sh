# What the TUM fr1/xyz tracking benchmarks (track_fr1.sh, track_fr1_live.sh) share: their defaults,
# the options both take, the checks of binaries and data, and a trajectory's ATE. Sourced, not run:
# the caller sets `set -euo pipefail` and may define own_option (below) before fr1_parse_args.

here="$(cd "$(dirname "${BASH_SOURCE[0]}")/../.." && pwd)"
py=/usr/bin/python3
me="$(basename "$0")"
bins=()
data=/work/shared/datasets/tum_fr1_xyz
work="/tmp/${me%.sh}.${USER:-$(id -un)}"

fr1_die() {  # status message...
  local status=$1
  shift
  echo "$me: $*" >&2
  exit "$status"
}

# The caller's header comment (after the #! line) as its --help.
fr1_usage() {
  awk 'NR > 1 && /^#/ { sub(/^# ?/, ""); print; next } NR > 1 { exit }' "$0"
}

# --bin, --data, --work and --help here; any other option goes to the caller's
# `own_option NAME VALUE`, which returns 0 when it took the option and its value.
fr1_parse_args() {
  while [[ $# -gt 0 ]]; do
    case "$1" in
      --bin) bins+=("$2"); shift 2 ;;
      --data) data="$2"; shift 2 ;;
      --work) work="$2"; shift 2 ;;
      -h|--help) fr1_usage; exit 0 ;;
      *)
        if declare -F own_option > /dev/null && own_option "$1" "${2-}"; then
          shift 2
        else
          fr1_die 2 "unknown argument $1 (--help)"
        fi ;;
    esac
  done
}

# One or two --bin (default build/bin), each with every program named; and a data folder with
# depth.txt and groundtruth.txt.
fr1_check_inputs() {  # program...
  [[ ${#bins[@]} -eq 0 ]] && bins=("$here/build/bin")
  [[ ${#bins[@]} -gt 2 ]] && fr1_die 2 "at most two --bin"
  local b p
  for b in "${bins[@]}"; do
    for p in "$@"; do
      [[ -x "$b/$p" ]] || fr1_die 2 "no $b/$p"
    done
  done
  [[ -f "$data/depth.txt" && -f "$data/groundtruth.txt" ]] ||
    fr1_die 2 "$data has no depth.txt and groundtruth.txt"
}

# A trajectory's ATE against the ground truth (tools/eval/ate.py: nearest stamp within 20 ms, best
# rigid fit; per-frame errors to ERRORS), printed as FORMAT (Python %) of ate.py's FIELDS.
fr1_ate() {  # trajectory groundtruth errors "field..." format
  local ate
  ate=$("$py" "$here/tools/eval/ate.py" "$1" "$2" --json --per-frame "$3")
  "$py" -c 'import json,sys; a=json.loads(sys.argv[1]); print(sys.argv[3] % tuple(a[f] for f in sys.argv[2].split()))' \
    "$ate" "$4" "$5"
}

fr1_load() {
  echo "load: $(cut -d' ' -f1-3 /proc/loadavg)"
  echo
}
