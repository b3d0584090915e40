# shellcheck shell=bash disable=SC2034
# Shared by the deploy tests (sourced). Each test is a real run of the tool it checks; when that
# tool or privilege is missing here the test exits 77 (CTest: skipped) and says why.

SKIP=77
fail() { echo "FAIL: $*" >&2; exit 1; }
skip() { echo "SKIP: $*"; exit "$SKIP"; }
note() { echo "NOTE: $*"; }
need() { command -v "$1" >/dev/null 2>&1 || skip "$1 is not installed${2:+ ($2)}"; }

# A temporary directory removed on exit.
make_workdir() {
  WORK=$(mktemp -d "${TMPDIR:-/tmp}/depthfuse-deploy-XXXXXX")
  trap 'rm -rf "$WORK"' EXIT
}

# Copies the host's systemd units into a root (without overwriting), so that systemd-analyze
# verify --root finds sysinit.target, basic.target, network.target ... there.
add_host_units() {
  local root=$1
  mkdir -p "$root/usr/lib/systemd/system"
  local d
  for d in /usr/lib/systemd/system /lib/systemd/system; do
    if [ -d "$d" ]; then cp -rn "$d/." "$root/usr/lib/systemd/system/" 2>/dev/null || true; fi
  done
}

# systemd-analyze verify of units installed in a root. Fails on any message about a depthfuse
# unit (systemd-analyze exits 0 after "Unknown key" warnings, so its output is what counts).
verify_units_in_root() {
  local root=$1; shift
  local unit out rc
  for unit in "$@"; do
    [ -f "$root/usr/lib/systemd/system/$unit" ] || fail "$unit is not installed in $root"
    rc=0
    out=$(systemd-analyze verify --man=no --root="$root" "$unit" 2>&1) || rc=$?
    if [ "$rc" -ne 0 ] || printf '%s\n' "$out" | grep -q depthfuse; then
      printf '%s\n' "$out" >&2
      fail "systemd-analyze verify $unit (exit $rc)"
    fi
    echo "ok: systemd-analyze verify $unit"
  done
}

DEPTHFUSE_UNITS="depthfuse.target depthfuse-capture.service depthfuse-fusion.service depthfuse-monitor.service depthfuse-lcm-route.service"
DEPTHFUSE_DAEMONS="depthfuse-capture depthfuse-fusion depthfuse-monitor"
