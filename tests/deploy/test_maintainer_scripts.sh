#!/usr/bin/env bash
# The maintainer scripts on a *running* system, which no test here can boot: in a private mount
# namespace, /run/systemd/system exists (systemd "is running") and the commands the scripts call
# (systemctl, udevadm, systemd-sysusers, systemd-tmpfiles, systemd-detect-virt, systemd-sysctl)
# are recorders that log their arguments. Checks what is called in each case: first install,
# upgrade, a daemon that fails to start, a chroot, no systemd, remove, purge. (The real tools
# run in test_package.sh, through dpkg --root.) Nothing outside the namespace is touched.
#
# usage: test_maintainer_scripts.sh <systemd/debian directory>
set -euo pipefail
. "$(dirname "$0")/lib.sh"

SCRIPTS=$(realpath "${1:?usage: test_maintainer_scripts.sh <dir with postinst prerm postrm>}")
need unshare "package util-linux"
unshare -m true 2>/dev/null || skip "cannot create a mount namespace here (needs root or CAP_SYS_ADMIN)"
# The scripts call systemd-sysctl by its path: it must be there on Debian 12.
[ -x /usr/lib/systemd/systemd-sysctl ] || skip "/usr/lib/systemd/systemd-sysctl is missing (package systemd)"
make_workdir

mkdir -p "$WORK/bin"
for tool in systemctl udevadm systemd-sysusers systemd-tmpfiles systemd-detect-virt systemd-sysctl; do
  cat >"$WORK/bin/$tool" <<STUB
#!/bin/sh
echo "$tool \$*" >>"$WORK/log"
# FAIL_<tool> makes one call fail; systemd-detect-virt answers "not a chroot" unless IN_CHROOT=1.
case "$tool" in
  systemd-detect-virt) [ "\${IN_CHROOT:-0}" = 1 ] && exit 0; exit 1 ;;
esac
[ "\${FAIL_TOOL:-}" = "$tool \$1" ] && exit 1
exit 0
STUB
  chmod 755 "$WORK/bin/$tool"
done

cat >"$WORK/in-ns.sh" <<'BODY'
set -euo pipefail
SCRIPTS=$1; WORK=$2
fail() { echo "FAIL: $*" >&2; echo "--- calls:" >&2; cat "$WORK/log" >&2 2>/dev/null; exit 1; }
mount -t tmpfs none /run
mkdir -p /run/systemd/system
mount --bind "$WORK/bin/systemd-sysctl" /usr/lib/systemd/systemd-sysctl
# /etc as the scripts see it: the host's, with what they write (the rig key) kept in this
# namespace, and the group that systemd-sysusers (a stub here) would have made.
mkdir -p "$WORK/etc-overlay"
mount -t tmpfs none "$WORK/etc-overlay"
mkdir -p "$WORK/etc-overlay/upper" "$WORK/etc-overlay/work"
mount -t overlay overlay \
  -o "lowerdir=/etc,upperdir=$WORK/etc-overlay/upper,workdir=$WORK/etc-overlay/work" /etc
grep -q '^depthfuse:' /etc/group || echo "depthfuse:x:64999:" >>/etc/group
export PATH="$WORK/bin:$PATH"
unset DPKG_ROOT

run() {  # run <script> <args...>: fresh log, must exit 0
  : >"$WORK/log"
  sh "$SCRIPTS/$1" "${@:2}" >"$WORK/out" 2>&1 || { cat "$WORK/out" >&2; fail "$* exited non-zero"; }
}
called() { grep -qxF -- "$1" "$WORK/log" || fail "expected the call: $1"; }
not_called() { if grep -q -- "$1" "$WORK/log"; then fail "unexpected call matching: $1"; fi; }
order() {  # order <first> <second>: both called, first before second
  local a b
  a=$(grep -nxF -- "$1" "$WORK/log" | head -n 1 | cut -d: -f1)
  b=$(grep -nxF -- "$2" "$WORK/log" | head -n 1 | cut -d: -f1)
  [ -n "$a" ] && [ -n "$b" ] && [ "$a" -lt "$b" ] || fail "expected '$1' before '$2'"
}
UNITS="depthfuse.target depthfuse-lcm-route.service depthfuse-capture.service depthfuse-fusion.service depthfuse-monitor.service"

# First installation on a running system.
run postinst configure ""
called "systemd-sysusers depthfuse.conf"
called "systemd-tmpfiles --create depthfuse.conf"
order "systemd-sysusers depthfuse.conf" "systemd-tmpfiles --create depthfuse.conf"
called "systemctl --quiet enable $UNITS"
called "systemd-sysctl 60-depthfuse.conf"
called "udevadm control --reload-rules"
called "udevadm trigger --action=add --subsystem-match=usb --attr-match=idVendor=045e"
called "systemctl daemon-reload"
called "systemctl start depthfuse.target"
order "systemctl daemon-reload" "systemctl start depthfuse.target"
KEY=/etc/depthfuse/rig.key
grep -qxE '[0-9a-f]{64}' "$KEY" || fail "postinst made no rig key of 64 hex digits: $(cat "$KEY" 2>&1)"
[ "$(stat -c %a:%G "$KEY")" = 640:depthfuse ] || fail "$KEY is $(stat -c %a:%G "$KEY"), want 640:depthfuse"
first_key=$(cat "$KEY")
echo "ok: first installation"

# Upgrade: nothing enabled again, the daemons restarted.
run postinst configure 0.1.0-1
not_called "enable"
not_called "systemctl start"
called "systemctl try-restart depthfuse-lcm-route.service depthfuse-capture.service depthfuse-fusion.service depthfuse-monitor.service"
[ "$(cat "$KEY")" = "$first_key" ] || fail "an upgrade replaced the rig key"
echo "ok: upgrade"

# A daemon that does not start, or a sysctl that does not apply, does not fail the installation.
FAIL_TOOL="systemctl start" run postinst configure ""
grep -q "did not start" "$WORK/out" || fail "no warning when the appliance does not start"
FAIL_TOOL="systemd-sysctl 60-depthfuse.conf" run postinst configure ""
grep -q "applies at the next boot" "$WORK/out" || fail "no warning when the sysctl does not apply"
echo "ok: failures to start or apply are warnings"

# In a chroot, or without systemd: files and enablement only.
for mode in chroot no-systemd; do
  if [ "$mode" = chroot ]; then export IN_CHROOT=1; else unset IN_CHROOT; rmdir /run/systemd/system; fi
  run postinst configure ""
  called "systemd-sysusers depthfuse.conf"
  called "systemctl --quiet enable $UNITS"
  for c in daemon-reload "systemctl start" try-restart udevadm systemd-sysctl; do not_called "$c"; done
  run prerm remove
  not_called "systemctl stop"
  run postrm purge
  not_called "daemon-reload"
  echo "ok: $mode: nothing started, reloaded or applied"
done
unset IN_CHROOT
mkdir -p /run/systemd/system

# Removal: disabled, then the daemons stopped before the route.
run prerm remove
called "systemctl --quiet disable $UNITS"
called "systemctl stop depthfuse.target depthfuse-capture.service depthfuse-fusion.service depthfuse-monitor.service"
order "systemctl stop depthfuse.target depthfuse-capture.service depthfuse-fusion.service depthfuse-monitor.service" \
      "systemctl stop depthfuse-lcm-route.service"
FAIL_TOOL="systemctl stop" run prerm remove   # a unit that fails to stop does not block removal
run prerm upgrade
[ ! -s "$WORK/log" ] || fail "prerm upgrade must leave the running appliance alone"
run postinst configure ""  # a rig key again: the purges above took it
run postrm remove
called "systemctl daemon-reload"
called "udevadm control --reload-rules"
[ -e "$KEY" ] || fail "postrm remove (not purge) deleted the rig key"
run postrm purge
called "systemctl daemon-reload"
[ ! -e "$KEY" ] || fail "postrm purge left the rig key"
echo "ok: remove and purge"

for s in postinst prerm postrm; do
  if sh "$SCRIPTS/$s" bogus >/dev/null 2>&1; then fail "$s accepts an unknown action"; fi
done
echo PASS
BODY

unshare -m bash "$WORK/in-ns.sh" "$SCRIPTS" "$WORK"
