#!/usr/bin/env bash
# The Debian package: `cpack -G DEB` from the configured build tree into a temporary directory,
# then its control data and contents (binaries, units, udev rule, sysctl, sysusers, tmpfiles,
# configuration as a conffile, maintainer scripts), its Depends against the libraries the
# binaries really link, and a real installation into a throwaway root with `dpkg --root`
# (maintainer scripts included, run for that root), where the units are verified with
# systemd-analyze. Then upgrade, remove and purge in that root. The host is never touched.
#
# usage: test_package.sh <build-dir> <source-dir> <daemon-target>=<0|1> ...
set -euo pipefail
. "$(dirname "$0")/lib.sh"

BUILD=$(realpath "${1:?usage: test_package.sh <build-dir> <source-dir> name=0|1 ...}")
SRC=$(realpath "${2:?}")
shift 2
need cpack
need dpkg-deb "package dpkg"
need dpkg-shlibdeps "package dpkg-dev"
need readelf "package binutils"
make_workdir

# --- build the package -------------------------------------------------------------------------
if ! cpack -G DEB --config "$BUILD/CPackConfig.cmake" -B "$WORK/pkg" >"$WORK/cpack.log" 2>&1; then
  cat "$WORK/cpack.log" >&2
  fail "cpack -G DEB failed (is the whole tree built? run ninja first)"
fi
DEB=$(find "$WORK/pkg" -maxdepth 1 -name 'depthfuse_*.deb' | head -n 1)
[ -n "$DEB" ] || { cat "$WORK/cpack.log" >&2; fail "cpack made no depthfuse_*.deb"; }
echo "ok: built $(basename "$DEB") ($(du -h "$DEB" | cut -f1))"

# --- control data ------------------------------------------------------------------------------
field() { dpkg-deb -f "$DEB" "$1"; }
[ "$(field Package)" = depthfuse ] || fail "Package is '$(field Package)'"
version=$(sed -n 's/^project(depthfuse VERSION \([0-9.]*\).*/\1/p' "$SRC/CMakeLists.txt")
[ "$(field Version)" = "$version-1" ] || fail "Version is '$(field Version)', the project is $version"
[ "$(field Architecture)" = "$(dpkg --print-architecture)" ] || fail "Architecture is '$(field Architecture)'"
[ -n "$(field Maintainer)" ] || fail "no Maintainer"
[ -n "$(field Description)" ] || fail "no Description"
DEPENDS=$(field Depends)
echo "Depends: $DEPENDS"
# Package names in Depends, without versions or alternatives' separators.
dep_names=" $(printf '%s\n' "$DEPENDS" | tr ',|' '\n' | sed 's/(.*)//; s/^ *//; s/ *$//' | tr '\n' ' ') "
has_dep() { case "$dep_names" in *" $1 "*) return 0;; *) return 1;; esac; }
for p in systemd iproute2; do has_dep "$p" || fail "Depends lacks $p"; done

dpkg-deb -e "$DEB" "$WORK/control"
grep -qx /etc/depthfuse/depthfuse.toml "$WORK/control/conffiles" || fail "depthfuse.toml is not a conffile"
for s in postinst prerm postrm; do
  [ -x "$WORK/control/$s" ] || fail "maintainer script $s missing or not executable"
  sh -n "$WORK/control/$s" || fail "$s is not valid sh"
done

# --- contents ----------------------------------------------------------------------------------
dpkg-deb -c "$DEB" | awk '{print $6}' | sed 's|^\./|/|; s|/$||' | sort >"$WORK/files"
expect_file() { grep -qxF "$1" "$WORK/files" || fail "the package lacks $1"; }
expect_file /usr/bin/depthfuse
for arg in "$@"; do
  name=${arg%%=*}
  if [ "${arg#*=}" = 1 ]; then
    expect_file "/usr/bin/$name"
  else
    note "$name is not built in this tree (no such target yet): not in the package"
  fi
done
for u in $DEPTHFUSE_UNITS; do expect_file "/usr/lib/systemd/system/$u"; done
expect_file /usr/lib/depthfuse/depthfuse-lcm-route
expect_file /usr/lib/udev/rules.d/60-depthfuse-kinect2.rules
expect_file /usr/lib/sysctl.d/60-depthfuse.conf
expect_file /usr/lib/sysusers.d/depthfuse.conf
expect_file /usr/lib/tmpfiles.d/depthfuse.conf
expect_file /etc/depthfuse/depthfuse.toml
expect_file /usr/share/doc/depthfuse/deployment.md
# The operator's page, three.js and TweetNaCl (copied from Debian's packages at build time): it
# works offline.
for arg in "$@"; do
  if [ "$arg" = depthfuse-monitor=1 ]; then
    for f in index.html app.js command_auth.js style.css three.min.js OrbitControls.js nacl.min.js; do
      expect_file "/usr/share/depthfuse/web/$f"
    done
  fi
done
# Nothing outside /usr and /etc, nothing from the build tree.
if grep -vE '^/(usr|etc)(/|$)|^/$|^$' "$WORK/files"; then fail "files outside /usr and /etc (above)"; fi
if grep -E '/usr/local|/work/|build-' "$WORK/files"; then fail "build-tree paths in the package (above)"; fi
echo "ok: $(wc -l <"$WORK/files") paths, the expected ones among them"

dpkg-deb -x "$DEB" "$WORK/x"
cmp -s "$WORK/x/etc/depthfuse/depthfuse.toml" "$SRC/config/depthfuse.toml" ||
  fail "the packaged depthfuse.toml differs from config/depthfuse.toml"
cmp -s "$WORK/x/usr/lib/udev/rules.d/60-depthfuse-kinect2.rules" "$SRC/systemd/60-depthfuse-kinect2.rules" ||
  fail "the packaged udev rule differs from systemd/60-depthfuse-kinect2.rules"
[ -x "$WORK/x/usr/lib/depthfuse/depthfuse-lcm-route" ] || fail "depthfuse-lcm-route is not executable"

# --- dependencies: every library an ELF file needs is bundled (RUNPATH) or comes from a package in
# Depends; a bundled one is one that no Debian package here provides (libfreenect2 from source).
lib_package() {  # the installed package that owns the library file named $1 (a soname)
  local path candidate owner
  path=$(ldconfig -p | awk -v so="$1" '$1 == so && /x86-64|x86_64|64bit/ {print $NF; exit}')
  [ -n "$path" ] || path=$(ldconfig -p | awk -v so="$1" '$1 == so {print $NF; exit}')
  [ -n "$path" ] || return 1
  for candidate in "$path" "$(realpath "$path")" "${path#/usr}" "/usr$path"; do
    owner=$(dpkg -S "$candidate" 2>/dev/null | head -n 1 | cut -d: -f1) && [ -n "$owner" ] && {
      echo "$owner"; return 0; }
  done
  return 1
}
elf_count=0
while IFS= read -r f; do
  readelf -h "$f" >/dev/null 2>&1 || continue
  elf_count=$((elf_count + 1))
  runpath=$(readelf -d "$f" | sed -n 's/.*(RUNPATH).*\[\(.*\)\]/\1/p')
  for so in $(readelf -d "$f" | sed -n 's/.*(NEEDED).*\[\(.*\)\]/\1/p'); do
    bundled=""
    IFS=: read -ra dirs <<<"$runpath"
    for dir in "${dirs[@]}"; do
      dir=${dir//\$ORIGIN/$(dirname "$f")}
      if [ -n "$dir" ] && [ -e "$dir/$so" ]; then bundled=$dir/$so; fi
    done
    if [ -n "$bundled" ]; then
      if pkg=$(lib_package "$so"); then fail "$so is bundled although package $pkg provides it"; fi
      echo "ok: ${f#"$WORK"/x} finds $so bundled in $(dirname "${bundled#"$WORK"/x}")"
      continue
    fi
    pkg=$(lib_package "$so") || fail "${f#"$WORK"/x}: needs $so, which neither the package nor an installed Debian package provides"
    has_dep "$pkg" || fail "${f#"$WORK"/x} needs $so from $pkg, which is not in Depends"
  done
done < <(find "$WORK/x" -type f)
[ "$elf_count" -ge 1 ] || fail "no binaries in the package"
echo "ok: the libraries of $elf_count ELF files are bundled or come from packages in Depends"

# --- debug symbols: stripped binaries, their symbols in the -dbgsym package ----------------------
DDEB=$(find "$WORK/pkg" -maxdepth 1 -name 'depthfuse-dbgsym_*.ddeb' | head -n 1)
[ -n "$DDEB" ] || fail "cpack made no depthfuse-dbgsym_*.ddeb"
[ "$(dpkg-deb -f "$DDEB" Depends)" = "depthfuse (= $version-1)" ] || fail "dbgsym Depends is '$(dpkg-deb -f "$DDEB" Depends)'"
build_ids=" $(dpkg-deb -f "$DDEB" Build-Ids) "
while IFS= read -r f; do
  readelf -h "$f" >/dev/null 2>&1 || continue
  if readelf -S "$f" | grep -q '\.debug_info'; then fail "${f#"$WORK"/x} is not stripped"; fi
  id=$(readelf -n "$f" | sed -n 's/.*Build ID: *\([0-9a-f]*\).*/\1/p')
  [ -n "$id" ] || fail "${f#"$WORK"/x} has no build id"
  case "$build_ids" in *" $id "*) ;; *) fail "${f#"$WORK"/x}: no symbols in the dbgsym package";; esac
done < <(find "$WORK/x" -type f)
echo "ok: binaries stripped, their symbols in $(basename "$DDEB")"

# --- install into a throwaway root -------------------------------------------------------------
if [ "$(id -u)" -ne 0 ]; then
  note "not root: dpkg cannot set file owners, the installation into a throwaway root is skipped"
  echo PASS
  exit 0
fi
need dpkg
need systemd-sysusers "package systemd"
need systemd-tmpfiles "package systemd"
need systemctl "package systemd"
R=$WORK/root
mkdir -p "$R/var/lib/dpkg/info" "$R/var/lib/dpkg/updates" "$R/var/lib/dpkg/triggers" "$R/etc"
touch "$R/var/lib/dpkg/status"
# A root with the base accounts, as on any Debian system.
grep -E '^(root|daemon|nobody):' /etc/passwd >"$R/etc/passwd"
grep -E '^(root|daemon|nogroup):' /etc/group >"$R/etc/group"
# The host's units (sysinit.target, multi-user.target ...) for systemctl and systemd-analyze.
add_host_units "$R"
DPKG=(dpkg --root="$R" --log="$WORK/dpkg.log" --force-script-chrootless --force-depends
      --force-not-root)
if ! "${DPKG[@]}" -i "$DEB" >"$WORK/install.log" 2>&1; then
  cat "$WORK/install.log" >&2
  fail "dpkg --root -i failed"
fi
# (dpkg's complaints about the dependencies, absent from this empty root, left out)
grep -vE '^ depthfuse depends on|^  Package .* is not installed|dependency problems, but configuring' \
  "$WORK/install.log" || true

# postinst did its work in the root.
uid=$(awk -F: '$1 == "depthfuse" {print $3}' "$R/etc/passwd")
[ -n "$uid" ] || fail "postinst did not create the user depthfuse (systemd-sysusers)"
gid=$(awk -F: '$1 == "depthfuse" {print $3}' "$R/etc/group")
[ -n "$gid" ] || fail "postinst did not create the group depthfuse"
[ "$(awk -F: '$1 == "depthfuse" {print $7}' "$R/etc/passwd")" != /bin/bash ] || fail "depthfuse has a login shell"
for d in /var/lib/depthfuse /var/lib/depthfuse/scans; do
  [ -d "$R$d" ] || fail "postinst did not create $d (systemd-tmpfiles)"
  [ "$(stat -c %u:%g:%a "$R$d")" = "$uid:$gid:750" ] || fail "$d is $(stat -c %u:%g:%a "$R$d"), want $uid:$gid:750"
done
W=$R/etc/systemd/system
[ -L "$W/multi-user.target.wants/depthfuse.target" ] || fail "depthfuse.target is not enabled"
for d in $DEPTHFUSE_DAEMONS; do
  [ -L "$W/depthfuse.target.wants/$d.service" ] || fail "$d.service is not enabled"
done
KEY=$R/etc/depthfuse/rig.key
grep -qxE '[0-9a-f]{64}' "$KEY" || fail "postinst made no rig key of 64 hex digits"
[ "$(stat -c %a:%g "$KEY")" = "640:$gid" ] || fail "rig.key is $(stat -c %a:%g "$KEY"), want 640:$gid"
echo "ok: user depthfuse ($uid:$gid), /var/lib/depthfuse/scans, units enabled, rig key"

# The units as installed, against the binaries as installed.
for arg in "$@"; do
  name=${arg%%=*}
  if [ "${arg#*=}" != 1 ] && [ ! -e "$R/usr/bin/$name" ]; then
    printf '#!/bin/sh\nexit 0\n' >"$R/usr/bin/$name"; chmod 755 "$R/usr/bin/$name"  # noted above
  fi
done
if command -v systemd-analyze >/dev/null; then
  # shellcheck disable=SC2086
  verify_units_in_root "$R" $DEPTHFUSE_UNITS
else
  note "systemd-analyze is not installed: units in the installed root not verified"
fi

# --- upgrade: an administrator's choices survive -----------------------------------------------
echo "# edited on the rig" >>"$R/etc/depthfuse/depthfuse.toml"
systemctl --root="$R" --quiet disable depthfuse-monitor.service
"${DPKG[@]}" --force-confold -i "$DEB" >"$WORK/upgrade.log" 2>&1 || { cat "$WORK/upgrade.log" >&2; fail "reinstall failed"; }
tail -n 1 "$R/etc/depthfuse/depthfuse.toml" | grep -qx "# edited on the rig" || fail "an upgrade replaced the edited config"
[ ! -e "$W/depthfuse.target.wants/depthfuse-monitor.service" ] || fail "an upgrade re-enabled a disabled unit"
[ -L "$W/depthfuse.target.wants/depthfuse-fusion.service" ] || fail "an upgrade disabled a unit"
echo "ok: upgrade keeps the edited config and the disabled unit"

# --- remove, then purge --------------------------------------------------------------------------
touch "$R/var/lib/depthfuse/scans/scan-0001.ply"
"${DPKG[@]}" -r depthfuse >"$WORK/remove.log" 2>&1 || { cat "$WORK/remove.log" >&2; fail "dpkg -r failed"; }
[ ! -e "$R/usr/bin/depthfuse" ] || fail "remove left /usr/bin/depthfuse"
[ ! -e "$R/usr/lib/systemd/system/depthfuse-fusion.service" ] || fail "remove left the units"
if find "$W" -name 'depthfuse*' | grep .; then fail "remove left enablement links (above)"; fi
[ -f "$R/etc/depthfuse/depthfuse.toml" ] || fail "remove (not purge) deleted the conffile"
"${DPKG[@]}" --purge depthfuse >"$WORK/purge.log" 2>&1 || { cat "$WORK/purge.log" >&2; fail "dpkg --purge failed"; }
[ ! -e "$R/etc/depthfuse/depthfuse.toml" ] || fail "purge left the conffile"
[ ! -e "$KEY" ] || fail "purge left the rig key"
[ -f "$R/var/lib/depthfuse/scans/scan-0001.ply" ] || fail "purge deleted a scan"
echo "ok: remove and purge (scans kept)"
echo PASS
