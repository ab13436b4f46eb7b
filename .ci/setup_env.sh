#!/usr/bin/env bash
# Creates .venv, installs the pinned requirements (skipped when unchanged) and the project
# itself, makes sure open3d can load (Debian's libusb-1.0-0) and builds the interface
# package geomodel_msgs into the venv (skipped when unchanged). Idempotent.
set -euo pipefail
cd "$(dirname "$0")/.."
VENV=.venv
REQ=.ci/requirements.txt
PY=${PYTHON:-python3}

if [ ! -x "$VENV/bin/python" ]; then
  echo "[setup] creating $VENV with $($PY --version)"
  "$PY" -m venv "$VENV"
fi

stamp="$VENV/.requirements.sha256"
want=$(cat "$REQ" setup.py | sha256sum | cut -d' ' -f1)
if [ "$(cat "$stamp" 2>/dev/null)" != "$want" ]; then
  echo "[setup] installing pinned requirements from $REQ"
  "$VENV/bin/python" -m pip install -q --disable-pip-version-check -r "$REQ"
  "$VENV/bin/python" -m pip install -q --disable-pip-version-check --no-deps --no-build-isolation -e .
  echo "$want" > "$stamp"
fi

# open3d's wheel links against libusb-1.0 from the system.
if ! "$VENV/bin/python" -c "import open3d" >/dev/null 2>&1; then
  if ! ldconfig -p 2>/dev/null | grep -q "libusb-1.0.so.0"; then
    if [ "$(id -u)" = 0 ] && command -v apt-get >/dev/null; then
      echo "[setup] installing Debian package libusb-1.0-0 (needed by open3d)"
      # Wait for another apt (an unattended upgrade, a second checkout's set-up) instead of
      # failing on its lock.
      apt_wait=(-o DPkg::Lock::Timeout=600)
      apt-get "${apt_wait[@]}" update -qq \
        && DEBIAN_FRONTEND=noninteractive apt-get "${apt_wait[@]}" install -y -qq libusb-1.0-0 >/dev/null
    else
      echo "error: open3d needs the system library libusb-1.0.so.0; install it with" >&2
      echo "       sudo apt-get install -y libusb-1.0-0   (then re-run make)" >&2
      exit 2
    fi
  fi
  "$VENV/bin/python" -c "import open3d" || { echo "error: open3d still fails to import (see above)" >&2; exit 2; }
fi

# The interface package geomodel_msgs (messages of the node), built into the venv.
bash .ci/build_msgs.sh

# `geomodel` on PATH of the venv (the console script itself is in lib/geomodel_ros/ for
# `ros2 run`).
bash .ci/install_geomodel_command.sh "$VENV/bin" "$VENV/bin/python"
