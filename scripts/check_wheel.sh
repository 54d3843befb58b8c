#!/usr/bin/env bash
# Use npga-view as a new user who runs `pip install .` would: build the sdist and the wheel (the wheel from the
# sdist), install the wheel with its dependencies into a fresh venv outside the checkout, and from another
# folder run --help, `info demo`, `render demo` to a PNG (checked not flat) and a short H.264 video (read back
# with PyAV). Usage: scripts/check_wheel.sh [BUILD_PYTHON]  (a Python with `build`; default .venv/bin/python).
# pip's cache is reused; the CPU torch is installed first (an unpinned torch would pull CUDA packages).
# KEEP_WORK=1 keeps the temporary folder (venv, x.png, x.mp4) and prints where it is.
set -euo pipefail
cd "$(dirname "$0")/.."
BUILD_PY=${1:-.venv/bin/python}
PY=${PYTHON:-python3}
TORCH_VERSION=${TORCH_VERSION:-2.13.0}
WORK=$(mktemp -d "${TMPDIR:-/tmp}/npga-wheel.XXXXXX")
if [ "${KEEP_WORK:-0}" = 1 ]; then trap 'echo "check_wheel: kept $WORK"' EXIT; else trap 'rm -rf "$WORK"' EXIT; fi
unset PYTHONPATH
started=$SECONDS

step() { echo "check_wheel: $*"; }

step "building the sdist and the wheel"
if ! "$BUILD_PY" -m build --outdir "$WORK/dist" . >"$WORK/build.log" 2>&1; then
  tail -40 "$WORK/build.log"
  exit 1
fi
wheel=$(ls "$WORK"/dist/*.whl)
sdist=$(ls "$WORK"/dist/*.tar.gz)
step "$(basename "$wheel") $(stat -c %s "$wheel") bytes, $(basename "$sdist") $(stat -c %s "$sdist") bytes"

step "installing into a fresh venv"
"$PY" -m venv "$WORK/venv"
VPY="$WORK/venv/bin/python"
pipq() { "$VPY" -m pip install -q "$@" 2>&1 | { grep -v "^WARNING: Location '" || true; }; }
pipq "torch==$TORCH_VERSION"
pipq "$wheel"
"$VPY" -c "import npga_view" # fails here if an install above failed

mkdir "$WORK/user"
cd "$WORK/user"
export XDG_CACHE_HOME="$WORK/cache" XDG_CONFIG_HOME="$WORK/config"
step "npga-view --help"
"$WORK/venv/bin/npga-view" --help >/dev/null
step "npga-view info demo"
"$WORK/venv/bin/npga-view" info demo >info.txt
head -3 info.txt
step "npga-view render demo --out x.png"
"$WORK/venv/bin/npga-view" render demo --out x.png
# a short sequence: the first 12 frames of a bundled demo animation
"$VPY" - <<'EOF'
from npga_core.files.loading import DEMO_DIR, load_sequence
from npga_core.files.sequences import ExpressionSequence
seq = load_sequence(DEMO_DIR / "sequences" / "talking.npzseq")
ExpressionSequence(seq.codes[:12], seq.fps, "short").save("short.npzseq")
print(f"check_wheel: short.npzseq: 12 frames at {seq.fps:g} fps")
EOF
step "npga-view render demo --sequence short.npzseq --out x.mp4"
"$WORK/venv/bin/npga-view" render demo --sequence short.npzseq --out x.mp4 --width 276 --height 402 2>/dev/null

"$VPY" - "$WORK" <<'EOF'
import sys
from pathlib import Path

import av
import cv2

import npga_core
from npga_core.files.loading import load_sequence

venv = Path(sys.argv[1]) / "venv"
assert Path(npga_core.__file__).resolve().is_relative_to(venv.resolve()), npga_core.__file__
first = Path("info.txt").read_text().splitlines()[0]
assert Path(first).resolve().is_relative_to(venv.resolve()), f"demo not from the install: {first}"
img = cv2.imread("x.png")
assert img is not None and img.std() > 10, "x.png is missing or flat"
fps = load_sequence("short.npzseq").fps
with av.open("x.mp4") as c:
    s = c.streams.video[0]
    frames = sum(1 for _ in c.decode(s))
    duration = float(s.duration * s.time_base)
    codec, pix = s.codec_context.name, s.codec_context.pix_fmt
assert (codec, pix, s.width, s.height) == ("h264", "yuv420p", 276, 402), (codec, pix, s.width, s.height)
assert frames == 12 and abs(duration - 12 / fps) < 1e-3, (frames, duration)
print(f"check_wheel: x.png {img.shape[1]}x{img.shape[0]} (std {img.std():.1f}); x.mp4 {codec} {pix} "
      f"{frames} frames, {duration:.3f} s")
EOF
step "passed in $((SECONDS - started)) s"
