#!/usr/bin/env bash
# One-step set-up on a fresh Debian 12, as root: installs the Debian packages depthfuse needs,
# builds it into build/, prepares LCM on this host, and runs the main job on the built-in default
# input (a synthetic scan of a concave corner with perturbed poses), leaving a fused cloud and a
# short report in out/demo/.
#
#   tools/setup.sh            everything
#   tools/setup.sh --no-demo  install and build only
set -euo pipefail
cd "$(dirname "$0")/.."

DEMO=1
[[ "${1:-}" == "--no-demo" ]] && DEMO=0

PACKAGES=(
  build-essential cmake ninja-build pkg-config git
  libeigen3-dev libpcl-dev libopencv-dev libusb-1.0-0-dev
  libsqlite3-dev sqlite3 libsystemd-dev systemd
  liblcm-dev liblcm-bin liblcm-java libglib2.0-dev default-jdk-headless
  libgtest-dev libgmock-dev libbenchmark-dev
  libtomlplusplus-dev libzstd-dev
  python3-open3d python3-numpy
  iproute2 procps dpkg-dev file udev
)

if [[ $(id -u) -eq 0 ]]; then
  missing=()
  for p in "${PACKAGES[@]}"; do
    dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed" || missing+=("$p")
  done
  if ((${#missing[@]})); then
    echo "== installing ${#missing[@]} Debian packages: ${missing[*]}"
    apt-get update -q
    DEBIAN_FRONTEND=noninteractive apt-get install -y -q --no-install-recommends "${missing[@]}"
  fi
  # LCM multicast needs a route; on a host whose only multicast-capable interface is lo (CI, a
  # bare namespace) add it there. A real rig gets this from depthfuse-lcm-route.service.
  if ! ip route get 239.255.76.67 >/dev/null 2>&1; then
    ip route add 224.0.0.0/4 dev lo || true
  fi
  # Frames are 7-14 UDP fragments: the receive buffer must hold several.
  if [[ $(sysctl -n net.core.rmem_max 2>/dev/null || echo 0) -lt 4194304 ]]; then
    sysctl -q -w net.core.rmem_max=4194304 || echo "note: could not raise net.core.rmem_max"
  fi
else
  echo "note: not root, skipping package installation and network set-up"
fi

echo "== building"
cmake -S . -B build -G Ninja -DCMAKE_BUILD_TYPE=RelWithDebInfo
cmake --build build -j"$(nproc)"
echo "programs are in build/bin/"

if ((DEMO)); then
  echo "== demo: a synthetic corner scan with poses off by ~2 cm / 1 degree"
  mkdir -p out/demo
  build/bin/depthfuse synth corner out/demo/corner --frames 40 --pose-noise-m 0.02 --pose-noise-deg 1
  build/bin/depthfuse reconstruct out/demo/corner --poses out/demo/corner/poses_perturbed.txt \
    --method full -o out/demo/cloud.ply --trajectory-out out/demo/trajectory.txt \
    --report out/demo/report.txt
  build/bin/depthfuse eval out/demo/corner out/demo/cloud.ply --trajectory out/demo/trajectory.txt \
    --out out/demo/eval | tee -a out/demo/report.txt
  echo "== done: out/demo/cloud.ply and out/demo/report.txt"
fi
