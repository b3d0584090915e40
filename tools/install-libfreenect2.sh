#!/usr/bin/env bash
# Builds and installs libfreenect2 for the kinect2 driver, from a source at hand. Debian does not
# package libfreenect2; depthfuse uses its USB transport, device commands, P0 tables and
# calibration, so only its CPU pipeline is built: TurboJPEG for colour, no OpenGL, OpenCL, CUDA,
# VA-API or Tegra JPEG (a scanning board has no GPU to give them), no examples, no OpenNI2 driver.
# Nothing of libfreenect2 is kept in this repository: the build happens in a temporary folder.
#
#   tools/install-libfreenect2.sh SOURCE [PREFIX]
#
# SOURCE is a libfreenect2 source folder, a tarball of one (.tar.gz, .tgz, .tar.xz, .tar), or a
# git URL to clone. PREFIX defaults to /usr/local; the driver's CMake finds libfreenect2 there
# through pkg-config (docs/kinect2.md says how to use another prefix).
set -euo pipefail

usage() { sed -n '2,13s/^# \{0,1\}//p' "$0"; }
[[ "${1:-}" == "-h" || "${1:-}" == "--help" ]] && { usage; exit 0; }
(($# >= 1 && $# <= 2)) || { usage >&2; exit 2; }
source_spec=$1
prefix=${2:-/usr/local}

say() { echo "install-libfreenect2: $*"; }
die() { echo "install-libfreenect2: $*" >&2; exit 1; }

for tool in cmake make c++ pkg-config; do
  command -v "$tool" >/dev/null || die "'$tool' is missing (Debian: build-essential cmake pkg-config)"
done
for pc in libusb-1.0 libturbojpeg; do
  pkg-config --exists "$pc" ||
    die "pkg-config finds no '$pc' (Debian: libusb-1.0-0-dev libturbojpeg0-dev)"
done

work=$(mktemp -d "${TMPDIR:-/tmp}/depthfuse-libfreenect2.XXXXXX")
trap 'rm -rf "$work"' EXIT

if [[ -d $source_spec ]]; then
  src=$(cd "$source_spec" && pwd)
  say "building from the folder $src"
elif [[ -f $source_spec ]]; then
  say "building from the tarball $source_spec"
  mkdir "$work/src"
  tar -xf "$source_spec" -C "$work/src" || die "cannot unpack $source_spec"
  src=$work/src
  # A tarball may hold the tree itself or one folder with it.
  if [[ ! -f $src/CMakeLists.txt ]]; then
    inner=("$src"/*/)
    ((${#inner[@]} == 1)) && src=${inner[0]%/}
  fi
else
  command -v git >/dev/null || die "'$source_spec' is no folder or file, and git is missing to clone it"
  say "cloning $source_spec"
  timeout 300 git clone --quiet --depth 1 "$source_spec" "$work/src" ||
    die "cannot clone '$source_spec' (is it a folder, a tarball or a reachable git URL?)"
  src=$work/src
fi
[[ -f $src/CMakeLists.txt && -f $src/include/libfreenect2/libfreenect2.hpp ]] ||
  die "$source_spec does not look like a libfreenect2 source tree (no include/libfreenect2/libfreenect2.hpp)"

cmake -S "$src" -B "$work/build" -DCMAKE_BUILD_TYPE=Release -DCMAKE_INSTALL_PREFIX="$prefix" \
  -DENABLE_CXX11=ON -DBUILD_EXAMPLES=OFF -DBUILD_OPENNI2_DRIVER=OFF \
  -DENABLE_OPENGL=OFF -DENABLE_OPENCL=OFF -DENABLE_CUDA=OFF -DENABLE_VAAPI=OFF \
  -DENABLE_TEGRAJPEG=OFF > "$work/configure.log" 2>&1 ||
  { tail -n 30 "$work/configure.log" >&2; die "libfreenect2's configure failed"; }
cmake --build "$work/build" -j"$(nproc)" > "$work/build.log" 2>&1 ||
  { tail -n 30 "$work/build.log" >&2; die "libfreenect2's build failed"; }
cmake --install "$work/build" > "$work/install.log" 2>&1 ||
  { tail -n 30 "$work/install.log" >&2; die "cannot install into $prefix (root?)"; }
command -v ldconfig >/dev/null && [[ $(id -u) -eq 0 ]] && ldconfig
version=$(PKG_CONFIG_PATH="$prefix/lib/pkgconfig:${PKG_CONFIG_PATH:-}" pkg-config --modversion freenect2 2>/dev/null || echo "?")
say "installed libfreenect2 $version into $prefix"
