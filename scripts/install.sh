#!/usr/bin/env bash
# Install everything npga-view needs on a fresh Debian/Ubuntu machine into a virtual environment.
# Usage: scripts/install.sh [VENV_DIR]   (default .venv). Safe to run again: it only adds what is missing.
set -euo pipefail
VENV=${1:-.venv}
PY=${PYTHON:-python3}
TORCH_VERSION=${TORCH_VERSION:-2.13.0}

# System libraries: EGL/GL for moderngl (headless too), X11 (imgui-bundle links it), Xvfb for window tests,
# OSMesa as the fallback headless GL.
APT_PKGS="libegl1 libgl1 libegl-mesa0 libgl1-mesa-dri libx11-6 libxext6 libosmesa6 xvfb"
if command -v apt-get >/dev/null 2>&1; then
  missing=""
  for p in $APT_PKGS; do dpkg -s "$p" >/dev/null 2>&1 || missing="$missing $p"; done
  if [ -n "$missing" ]; then
    SUDO=""; [ "$(id -u)" -ne 0 ] && SUDO="sudo"
    echo "installing system packages:$missing"
    $SUDO apt-get update -qq
    DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -qq --no-install-recommends $missing >/dev/null
  fi
else
  echo "note: no apt-get; make sure EGL/GL, X11 and Xvfb libraries are installed" >&2
fi

[ -x "$VENV/bin/python" ] || "$PY" -m venv "$VENV"
PIP="$VENV/bin/python -m pip"
# The pinned CPU torch first: an unpinned torch would pull several GB of CUDA packages.
# Elsewhere than our machines, set PIP_INDEX_URL=https://download.pytorch.org/whl/cpu for this step.
if ! "$VENV/bin/python" -c "import torch, sys; sys.exit(torch.__version__.split('+')[0] != '$TORCH_VERSION')" \
    2>/dev/null; then
  $PIP install -q "torch==$TORCH_VERSION"
fi
$PIP install -q -e ".[test]"
echo "npga-view installed in $VENV"
