#!/usr/bin/env bash
# One-step set-up on a fresh Debian 12, as root: installs the Debian packages depthfuse needs,
# builds it into build/, prepares LCM on this host, and runs the main job on the built-in default
# input (a synthetic scan of a concave corner with perturbed poses), leaving a fused cloud and a
# short report in out/demo/.
#
#   tools/setup.sh                         everything
#   tools/setup.sh --no-demo               install and build only
#   tools/setup.sh --libfreenect2 SOURCE   build the kinect2 driver's libfreenect2 from SOURCE
#
# libfreenect2 (the Kinect V2's USB driver) is not a Debian package. When it is not installed,
# set-up builds it from a source at hand (tools/install-libfreenect2.sh): the one given with
# --libfreenect2 (or $DEPTHFUSE_LIBFREENECT2_SOURCE), else the snapshot in
# ../shared/third_party/ when there is one, else a clone of the upstream repository when the
# network allows. Without any, the kinect2 driver is skipped and set-up says why.
set -euo pipefail
cd "$(dirname "$0")/.."

DEMO=1
LIBFREENECT2_SOURCE=${DEPTHFUSE_LIBFREENECT2_SOURCE:-}
while (($#)); do
  case "$1" in
    --no-demo) DEMO=0 ;;
    --libfreenect2)
      [[ $# -ge 2 ]] || { echo "setup: --libfreenect2 needs a folder, tarball or git URL" >&2; exit 2; }
      LIBFREENECT2_SOURCE=$2
      shift ;;
    -h|--help) sed -n '2,17s/^# \{0,1\}//p' "$0"; exit 0 ;;
    *) echo "setup: unknown option '$1' (see --help)" >&2; exit 2 ;;
  esac
  shift
done
LIBFREENECT2_UPSTREAM=https://github.com/OpenKinect/libfreenect2.git

PACKAGES=(
  build-essential cmake ninja-build pkg-config git
  libeigen3-dev libpcl-dev libopencv-dev libusb-1.0-0-dev
  libceres-dev                 # the pose graph optimiser (loop closure)
  libsqlite3-dev sqlite3 libsystemd-dev systemd
  liblcm-dev liblcm-bin liblcm-java libglib2.0-dev default-jdk-headless
  libgtest-dev libgmock-dev libbenchmark-dev
  libtomlplusplus-dev libzstd-dev libdeflate-dev libturbojpeg0-dev libsodium-dev
  libboost-dev libjs-three node-tweetnacl  # the operator's page: HTTP + WebSocket server
                                           # (Boost.Beast), three.js, SHA-512 for its command
                                           # signatures
  chromium openssl             # the page's tests: a real (headless) browser, a TLS proxy's key
  python3-open3d python3-numpy
  iproute2 procps dpkg-dev file udev
  clang libclang-rt-14-dev  # libFuzzer and the sanitizers for tools/fuzz.sh
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

# The kinect2 driver's libfreenect2, from the first source at hand.
if pkg-config --exists freenect2; then
  echo "== libfreenect2 $(pkg-config --modversion freenect2) is installed: the kinect2 driver is built"
elif [[ $(id -u) -ne 0 ]]; then
  echo "== kinect2 driver skipped: libfreenect2 is not installed, and installing it needs root"
else
  lf2_source=""
  if [[ -n $LIBFREENECT2_SOURCE ]]; then
    lf2_source=$LIBFREENECT2_SOURCE
  elif compgen -G "../shared/third_party/libfreenect2-*.tar.gz" >/dev/null; then
    lf2_source=$(compgen -G "../shared/third_party/libfreenect2-*.tar.gz" | sort | tail -n 1)
  elif timeout 20 git ls-remote --heads "$LIBFREENECT2_UPSTREAM" >/dev/null 2>&1; then
    lf2_source=$LIBFREENECT2_UPSTREAM
  fi
  if [[ -n $lf2_source ]]; then
    echo "== libfreenect2 is not installed: building it from $lf2_source"
    tools/install-libfreenect2.sh "$lf2_source"
  else
    echo "== kinect2 driver skipped: libfreenect2 is not installed, and no source is at hand" \
         "(no --libfreenect2 SOURCE, no ../shared/third_party/libfreenect2-*.tar.gz, and" \
         "$LIBFREENECT2_UPSTREAM is not reachable). See docs/kinect2.md."
  fi
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
