"""The real window measured on its pixels: `npga-view bench --window` (npga_view/benchmarks/bench_window.py).

    python benchmarks/bench_window.py [--gaussians 100000 250000] [--seconds 6] [--json out.json]
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))


def main() -> int:
    from npga_view.benchmarks.bench_window import run

    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--gaussians", type=int, nargs="*", default=[100000, 250000])
    p.add_argument("--no-demo", action="store_true")
    p.add_argument("--seconds", type=float, default=6.0)
    p.add_argument("--moves", type=int, default=6)
    p.add_argument("--json", type=Path)
    args = p.parse_args()
    run(args.gaussians, not args.no_demo, args.json, args.moves, args.seconds)
    return 0


if __name__ == "__main__":
    sys.exit(main())
