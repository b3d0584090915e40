#!/usr/bin/env bash
# 60-depthfuse-kinect2.rules through udev's own rule engine: `udevadm test` on fake USB devices in
# a private mount namespace (a tmpfs /sys with one device; the rule bind-mounted as the only file
# of /etc/udev/rules.d; a group file with depthfuse). Checks that the rule parses without a
# warning, that the three Kinect V2 ids get group depthfuse, mode 0660, the systemd and uaccess
# tags and SYSTEMD_WANTS, and that other devices are left alone. (systemd 252 has no
# `udevadm verify`.) Nothing outside the namespace is touched.
#
# usage: test_udev_rule.sh <rules file>
set -euo pipefail
. "$(dirname "$0")/lib.sh"

RULES=$(realpath "${1:?usage: test_udev_rule.sh <rules file>}")
need udevadm "package udev"
need unshare "package util-linux"
unshare -m true 2>/dev/null || skip "cannot create a mount namespace here (needs root or CAP_SYS_ADMIN)"
make_workdir

cat >"$WORK/in-ns.sh" <<'BODY'
set -euo pipefail
RULES=$1; WORK=$2
NAME=$(basename "$RULES")
fail() { echo "FAIL: $*" >&2; exit 1; }

# Our rule as the only local rule; a group file that has depthfuse; private /run and /dev for
# what `udevadm test` writes (its database, /dev/char links).
mkdir -p "$WORK/rules.d" "$WORK/sys"
cp "$RULES" "$WORK/rules.d/$NAME"
mount --bind "$WORK/rules.d" /etc/udev/rules.d
{ grep -v '^depthfuse:' /etc/group; echo "depthfuse:x:64123:"; } >"$WORK/group"
mount --bind "$WORK/group" /etc/group
mount -t tmpfs none /run
mount -t tmpfs none /dev
mknod -m 666 /dev/null c 1 3 2>/dev/null || touch /dev/null

# One fake USB device (or interface) in a tmpfs sysfs.
# usage: run <vendor> <product> <devtype> -> output of udevadm test in $WORK/out
run() {
  umount /sys 2>/dev/null || true
  mount -t tmpfs none /sys
  local d=/sys/devices/pci0000:00/0000:00:14.0/usb2/2-1
  mkdir -p /sys/bus/usb/devices "$d"
  ln -s ../../../../bus/usb "$d/subsystem"
  printf 'MAJOR=189\nMINOR=130\nDEVNAME=bus/usb/002/003\nDEVTYPE=%s\nPRODUCT=%s/%s/100\nBUSNUM=002\nDEVNUM=003\n' \
    "$3" "$1" "$2" >"$d/uevent"
  echo "$1" >"$d/idVendor"
  echo "$2" >"$d/idProduct"
  SYSTEMD_DEVICE_VERIFY_SYSFS=0 SYSTEMD_LOG_LEVEL=debug udevadm test --action=add "$d" >"$WORK/out" 2>&1 ||
    { cat "$WORK/out" >&2; fail "udevadm test failed for $1:$2"; }
}

run 045e 02c4 usb_device
# Parse-time messages about our file (line numbers without a device prefix) are rule errors.
if grep "rules.d/$NAME:" "$WORK/out" | grep -v '^2-1: ' | grep .; then
  fail "udev complains about $NAME (above)"
fi
grep -q "rules.d/$NAME:" "$WORK/out" || fail "udev did not read $NAME"

for product in 02c4 02d8 02d9; do
  run 045e "$product" usb_device
  grep -q "^2-1: .*$NAME:[0-9]* GROUP 64123" "$WORK/out" || { cat "$WORK/out" >&2; fail "045e:$product: group not set"; }
  grep -q "^2-1: .*$NAME:[0-9]* MODE 0660" "$WORK/out" || fail "045e:$product: mode not set"
  tags=$(sed -n 's/^TAGS=//p' "$WORK/out")
  case "$tags" in *:systemd:*) ;; *) fail "045e:$product: no systemd tag ($tags)";; esac
  case "$tags" in *:uaccess:*) ;; *) fail "045e:$product: no uaccess tag ($tags)";; esac
  grep -qx 'SYSTEMD_WANTS=depthfuse-capture.service' "$WORK/out" || fail "045e:$product: no SYSTEMD_WANTS"
  echo "ok: 045e:$product -> group depthfuse, mode 0660, tags $tags, wants depthfuse-capture.service"
done

# Not ours: a Kinect v1 camera, another vendor's 02c4, an interface of the Kinect V2.
for dev in "045e 02ae usb_device" "1234 02c4 usb_device" "045e 02c4 usb_interface"; do
  # shellcheck disable=SC2086
  run $dev
  if grep "^2-1: .*$NAME:" "$WORK/out" | grep -qE 'GROUP|MODE|TAG|SYSTEMD_WANTS'; then
    grep "$NAME" "$WORK/out" >&2
    fail "the rule touches $dev"
  fi
  if grep -q 'SYSTEMD_WANTS=depthfuse' "$WORK/out"; then fail "$dev wants depthfuse-capture"; fi
  echo "ok: $dev left alone"
done
echo PASS
BODY

unshare -m bash "$WORK/in-ns.sh" "$RULES" "$WORK"
