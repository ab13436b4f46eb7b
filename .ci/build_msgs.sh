#!/usr/bin/env bash
# Builds the interface package geomodel_msgs (ament_cmake + rosidl) with colcon and installs
# it into the venv, which the ROS wheels already use as their prefix (share/, lib/, include/,
# lib/python3.X/site-packages). There the generated Python package is importable and its
# libraries lie in <venv>/lib, which the wheels' start-up hook (ros_wheels_bootstrapper.pth)
# puts on LD_LIBRARY_PATH for every venv Python process, as it does for std_msgs & co.
# Nothing has to be sourced.
#
# Skipped when the package sources, this script and the venv did not change (stamp file in
# the venv). Run by .ci/setup_env.sh after the pinned requirements are installed.
set -euo pipefail
cd "$(dirname "$0")/.."
VENV=${VENV:-.venv}
PKG=geomodel_msgs
BUILD=build_msgs
V=$(cd "$VENV" && pwd)
STAMP="$V/.$PKG.sha256"

# What the build depends on: every file of the package, the build scripts, the venv
# (location, interpreter, installed requirements).
want=$( { find "$PKG" -type f -print0 | LC_ALL=C sort -z | xargs -0 sha256sum
          sha256sum .ci/build_msgs.sh .ci/fix_cmake_exports.py
          echo "$V"; readlink -f "$V/bin/python"
          cat "$V/.requirements.sha256" 2>/dev/null || true; } | sha256sum | cut -d' ' -f1)
if [ "$(cat "$STAMP" 2>/dev/null)" = "$want" ] && [ -f "$V/share/$PKG/package.xml" ]; then
  exit 0
fi

# Compilers and CMake come from Debian.
declare -A DEBIAN_PACKAGE=([gcc]=gcc [g++]=g++ [cmake]=cmake [make]=make)
missing=()
for tool in gcc g++ cmake make; do
  command -v "$tool" >/dev/null || missing+=("${DEBIAN_PACKAGE[$tool]}")
done
if [ ${#missing[@]} -gt 0 ]; then
  if [ "$(id -u)" = 0 ] && command -v apt-get >/dev/null; then
    echo "[setup] installing Debian packages ${missing[*]} (needed to build $PKG)"
    apt-get update -qq
    DEBIAN_FRONTEND=noninteractive apt-get install -y -qq "${missing[@]}" >/dev/null
  else
    echo "error: building $PKG needs ${missing[*]}; install them with" >&2
    echo "       sudo apt-get install -y ${missing[*]}   (then re-run make)" >&2
    exit 2
  fi
fi

# The message wheels' CMake exports name the wheel builder's include folders.
"$V/bin/python" .ci/fix_cmake_exports.py

# A previous install of this package: remove its files first so that nothing stale (e.g. a
# deleted message) survives in the venv.
# Then build from scratch: a cached CMake configuration may name another venv.
manifest="$BUILD/$PKG/install_manifest.txt"
if [ -f "$manifest" ]; then
  while IFS= read -r file; do
    case "$file" in "$V"/*) rm -f -- "$file" ;; esac
  done < "$manifest"
fi
rm -rf "${BUILD:?}/$PKG"

echo "[setup] building $PKG with colcon (install prefix $VENV)"
mkdir -p "$BUILD"
# A sourced ROS installation or workspace must not leak into the build: the venv is the
# only prefix (else "No 'rosidl_typesupport_c' found").
if ! env -u COLCON_PREFIX_PATH -u COLCON_CURRENT_PREFIX -u PYTHONPATH \
    AMENT_PREFIX_PATH="$V" CMAKE_PREFIX_PATH="$V" PATH="$V/bin:$PATH" \
    COLCON_HOME="$PWD/$BUILD/colcon_home" \
    "$V/bin/python" -m colcon --log-base "$BUILD/log" build \
      --paths "$PKG" --build-base "$BUILD" --install-base "$V" --merge-install \
      --event-handlers console_cohesion+ \
      --cmake-args -DBUILD_TESTING=OFF -DCMAKE_BUILD_TYPE=Release \
        "-DPython3_EXECUTABLE=$V/bin/python" > "$BUILD/build.log" 2>&1; then
  cat "$BUILD/build.log" >&2
  echo "error: building $PKG failed (log above and in $BUILD/log/latest_build)" >&2
  exit 2
fi
"$V/bin/python" -c "from $PKG.msg import PrimitiveArray" || {
  echo "error: $PKG was built but does not import (see above)" >&2; exit 2; }
echo "$want" > "$STAMP"
