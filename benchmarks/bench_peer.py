"""Full-resolution draw against GaussianSplattingViewer's OpenGL renderer (npga_view/benchmarks/bench_peer.py).

    python benchmarks/bench_peer.py --peer PATH/TO/GaussianSplattingViewer [--frames 15] [--size 1360x900]
           [--rounds 2] [--json out.json] [--screenshots DIR]

Skips with a message (exit 0) when no checkout is given (--peer or $NPGA_PEER_GSV).
"""

from __future__ import annotations

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))


if __name__ == "__main__":
    from npga_view.benchmarks.bench_peer import main

    sys.exit(main())
