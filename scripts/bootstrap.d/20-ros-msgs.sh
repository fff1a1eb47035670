#!/usr/bin/env bash
# Build the project's ROS 2 interfaces (interfaces/ether_ros_msgs) with the ROS 2 Jazzy wheels in
# .venv and install them into the venv itself: the libraries land in .venv/lib (which the wheels'
# bootstrapper already puts on LD_LIBRARY_PATH for every venv Python), the Python package in the
# venv's site-packages, the ament index entries in .venv/share. Skipped when the stamp matches the
# interface sources, so calling it every time costs nothing.
set -euo pipefail
SELF=$(realpath "$0")
cd "$(dirname "$SELF")/../.."

VENV=$PWD/.venv
PY=$VENV/bin/python
STAMPS=$VENV/.stamps
SRC=$PWD/interfaces/ether_ros_msgs
BUILD=$PWD/build/ros/ether_ros_msgs

log() { printf '[ros-msgs] %s\n' "$*"; }

# The wheels were built in a manylinux container: their exported CMake targets name that
# container's Python and numpy include directories. Point them at this venv's (idempotent: after
# the first run there is nothing left to replace; a reinstalled wheel is patched again).
py_include=$("$PY" -c 'import sysconfig; print(sysconfig.get_paths()["include"])')
np_include=$("$PY" -c 'import numpy; print(numpy.get_include())')
mapfile -t stale < <(grep -rl --include='*.cmake' '/opt/python/cp311-cp311' "$VENV/share" || true)
if [ ${#stale[@]} -gt 0 ]; then
  log "pointing ${#stale[@]} CMake exports at $py_include"
  sed -i \
    -e "s#/opt/python/cp311-cp311/lib/python3.11/site-packages/numpy/_core/include#$np_include#g" \
    -e "s#/opt/python/cp311-cp311/include/python3.11#$py_include#g" \
    "${stale[@]}"
fi

# Stamp: the interface sources, this script and the installed ROS wheels' versions.
src_hash=$( (cd "$SRC" && find . -type f \( -name '*.msg' -o -name '*.srv' -o -name 'CMakeLists.txt' \
  -o -name 'package.xml' \) -print0 | sort -z | xargs -0 sha256sum; cat "$SELF"; \
  ls "$VENV"/lib/python3.11/site-packages | grep -i '^ros_.*dist-info$' ) | sha256sum | cut -c1-16)
if [ -f "$STAMPS/ros-msgs" ] && [ "$(cat "$STAMPS/ros-msgs")" = "$src_hash" ] \
   && "$PY" -c 'import ether_ros_msgs.msg' 2>/dev/null; then
  exit 0
fi

log "building ether_ros_msgs"
export PATH=$VENV/bin:$PATH
export AMENT_PREFIX_PATH=$VENV      # ament_index_get_resources reads it to find the generators
rm -rf "$BUILD"
mkdir -p "$BUILD"
cmake -S "$SRC" -B "$BUILD" \
  -DCMAKE_BUILD_TYPE=Release \
  -DCMAKE_PREFIX_PATH="$VENV" \
  -DCMAKE_INSTALL_PREFIX="$VENV" \
  -DPython3_EXECUTABLE="$PY" \
  -DPYTHON_EXECUTABLE="$PY" \
  -DBUILD_TESTING=OFF > "$BUILD/configure.log" 2>&1 || { tail -40 "$BUILD/configure.log"; exit 1; }
cmake --build "$BUILD" -j "$(nproc)" > "$BUILD/build.log" 2>&1 || { tail -40 "$BUILD/build.log"; exit 1; }
cmake --install "$BUILD" > "$BUILD/install.log" 2>&1 || { tail -40 "$BUILD/install.log"; exit 1; }

"$PY" -c 'from ether_ros_msgs.msg import PdoRaw; from ether_ros_msgs.srv import Command; PdoRaw(); Command.Request()' \
  || { echo "ether_ros_msgs was built but does not import" >&2; exit 1; }
mkdir -p "$STAMPS"
printf '%s' "$src_hash" > "$STAMPS/ros-msgs"
log "ether_ros_msgs installed into $VENV"
