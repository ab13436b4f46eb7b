#!/usr/bin/env bash
# Writes the `geomodel` command into a bin/ folder: a small wrapper that runs
# `<python> -m geomodel_ros.cli "$@"`. The package's own console script lands in
# lib/geomodel_ros/ (setup.cfg redirects scripts there for `ros2 run`), so without this the
# venv's bin/ has no `geomodel`. Idempotent: the file is rewritten only when its content
# would change, and a `geomodel` that this script did not write is left alone.
#
# Usage: install_geomodel_command.sh <bin-dir> <python>   (run by .ci/setup_env.sh)
set -euo pipefail
if [ $# -ne 2 ]; then
  echo "usage: $0 <bin-dir> <python>" >&2
  exit 2
fi
BIN=$1
PYTHON=$(cd "$(dirname "$2")" && pwd)/$(basename "$2")
TARGET="$BIN/geomodel"
MARKER="# geomodel command of geomodel_ros (written by .ci/install_geomodel_command.sh)"

if [ -e "$TARGET" ] && ! grep -qxF "$MARKER" "$TARGET"; then
  echo "[setup] $TARGET exists and was not written by the set-up: left as it is"
  exit 0
fi
want=$(printf '#!/bin/sh\n%s\nexec "%s" -m geomodel_ros.cli "$@"\n' "$MARKER" "$PYTHON")
if [ "$(cat "$TARGET" 2>/dev/null)" != "$want" ]; then
  mkdir -p "$BIN"
  printf '%s\n' "$want" > "$TARGET.tmp"
  chmod 755 "$TARGET.tmp"
  mv -f "$TARGET.tmp" "$TARGET"
  echo "[setup] wrote $TARGET"
fi
