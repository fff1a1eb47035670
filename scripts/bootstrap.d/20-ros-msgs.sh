#!/usr/bin/env bash
# Build the project's ROS 2 interface packages with the ROS 2 Jazzy wheels in .venv and install
# them into the venv itself: the libraries land in .venv/lib (which the wheels' bootstrapper
# already puts on LD_LIBRARY_PATH for every venv Python), the Python packages in the venv's
# site-packages, the ament index entries in .venv/share. Each package is skipped when its stamp
# matches its sources, so calling this every time costs nothing.
#   interfaces/control_msgs   the FollowJointTrajectory action of ros-controls' control_msgs
#                             (Jazzy), which has no wheel: same package, types and fields
#   interfaces/ether_ros_msgs the project's own messages and services
set -euo pipefail
SELF=$(realpath "$0")
cd "$(dirname "$SELF")/../.."

VENV=$PWD/.venv
PY=$VENV/bin/python
STAMPS=$VENV/.stamps

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

# build_package NAME CHECK: configure, build and install interfaces/NAME unless its stamp (the
# interface sources, this script and the installed ROS wheels' versions) is current and the
# Python statement CHECK runs; CHECK must run after the build.
build_package() {
  local name=$1 check=$2
  local src=$PWD/interfaces/$name build=$PWD/build/ros/$name stamp=$STAMPS/ros-msgs-$name
  local src_hash
  src_hash=$( (cd "$src" && find . -type f \( -name '*.msg' -o -name '*.srv' -o -name '*.action' \
    -o -name 'CMakeLists.txt' -o -name 'package.xml' \) -print0 | sort -z | xargs -0 sha256sum; \
    cat "$SELF"; ls "$VENV"/lib/python3.11/site-packages | grep -i '^ros_.*dist-info$' ) \
    | sha256sum | cut -c1-16)
  if [ -f "$stamp" ] && [ "$(cat "$stamp")" = "$src_hash" ] && "$PY" -c "$check" 2>/dev/null; then
    return 0
  fi
  log "building $name"
  export PATH=$VENV/bin:$PATH
  export AMENT_PREFIX_PATH=$VENV      # ament_index_get_resources reads it to find the generators
  rm -rf "$build"
  mkdir -p "$build"
  cmake -S "$src" -B "$build" \
    -DCMAKE_BUILD_TYPE=Release \
    -DCMAKE_PREFIX_PATH="$VENV" \
    -DCMAKE_INSTALL_PREFIX="$VENV" \
    -DPython3_EXECUTABLE="$PY" \
    -DPYTHON_EXECUTABLE="$PY" \
    -DBUILD_TESTING=OFF > "$build/configure.log" 2>&1 || { tail -40 "$build/configure.log"; exit 1; }
  cmake --build "$build" -j "$(nproc)" > "$build/build.log" 2>&1 || { tail -40 "$build/build.log"; exit 1; }
  cmake --install "$build" > "$build/install.log" 2>&1 || { tail -40 "$build/install.log"; exit 1; }
  "$PY" -c "$check" || { echo "$name was built but does not import" >&2; exit 1; }
  mkdir -p "$STAMPS"
  printf '%s' "$src_hash" > "$stamp"
  log "$name installed into $VENV"
}

build_package control_msgs \
  'from control_msgs.action import FollowJointTrajectory; FollowJointTrajectory.Goal()'
build_package ether_ros_msgs \
  'from ether_ros_msgs.msg import PdoRaw; from ether_ros_msgs.srv import Command; PdoRaw(); Command.Request()'
