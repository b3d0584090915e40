#!/usr/bin/env bash
# depthfuse-lcm-route in a fresh network namespace (only loopback, down: what a rig without a
# network looks like to LCM): multicast fails before, works after `add`, `add` is idempotent,
# `remove` takes away only its own route, and an explicit multicast route is left alone.
#
# usage: test_lcm_route.sh <path of depthfuse-lcm-route>
set -euo pipefail
. "$(dirname "$0")/lib.sh"

SCRIPT=${1:?usage: test_lcm_route.sh <depthfuse-lcm-route>}
need ip "package iproute2"
need unshare "package util-linux"
PY=/usr/bin/python3
[ -x "$PY" ] || skip "/usr/bin/python3 is not installed"
unshare -n true 2>/dev/null || skip "cannot create a network namespace here (needs root or CAP_SYS_ADMIN)"
make_workdir

# The body runs inside the namespace; the state directory stands in for $RUNTIME_DIRECTORY.
cat >"$WORK/in-netns.sh" <<'BODY'
set -euo pipefail
SCRIPT=$1; PY=$2; HERE=$3; WORK=$4
export RUNTIME_DIRECTORY=$WORK/state
fail() { echo "FAIL: $*" >&2; exit 1; }
roundtrip() { "$PY" "$HERE/multicast_roundtrip.py" 239.255.76.67 7667; }
count_mc_routes() { ip -4 route show table main | grep -c '^224.0.0.0/4' || true; }

ip link set dev lo up
if roundtrip; then fail "multicast works without a route: this test cannot tell anything"; fi

"$SCRIPT" add
[ "$(count_mc_routes)" = 1 ] || fail "no 224.0.0.0/4 route after add: $(ip route)"
ip -4 route show table main | grep -q '^224.0.0.0/4 dev lo' || fail "route is not over lo: $(ip route)"
[ -e "$RUNTIME_DIRECTORY/route-added" ] || fail "add did not record that the route is its own"
roundtrip || fail "multicast does not work after add"

"$SCRIPT" add  # idempotent
[ "$(count_mc_routes)" = 1 ] || fail "second add changed the routes: $(ip route)"
roundtrip || fail "multicast broke after the second add"
"$SCRIPT" status

"$SCRIPT" remove
[ "$(count_mc_routes)" = 0 ] || fail "remove left the route: $(ip route)"
[ ! -e "$RUNTIME_DIRECTORY/route-added" ] || fail "remove left its mark"
"$SCRIPT" remove  # nothing to do, no error

# An administrator's explicit multicast route (here over lo too, no other device needed).
ip -4 route add 239.255.0.0/16 dev lo
"$SCRIPT" add
[ "$(count_mc_routes)" = 0 ] || fail "add routed 224.0.0.0/4 although 239.255.0.0/16 is routed"
"$SCRIPT" remove
ip -4 route show table main | grep -q '^239.255.0.0/16 dev lo' || fail "remove deleted a route that was not its own"

# A mark without the route (removed by hand meanwhile) is not an error either.
ip -4 route del 239.255.0.0/16 dev lo
"$SCRIPT" add
ip -4 route del 224.0.0.0/4 dev lo
"$SCRIPT" remove
[ ! -e "$RUNTIME_DIRECTORY/route-added" ] || fail "remove left its mark"

if "$SCRIPT" bogus 2>/dev/null; then fail "an unknown command must fail"; fi
echo PASS
BODY

unshare -n bash "$WORK/in-netns.sh" "$SCRIPT" "$PY" "$(cd "$(dirname "$0")" && pwd)" "$WORK"
