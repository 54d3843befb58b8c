"""Write stand-ins for the files of README "Driving ... Your own avatar", so its commands can be tried as written:

    python scripts/driving_example.py FOLDER

writes into FOLDER (then `cd FOLDER`):
- `gha_ckpt/`: a Gaussian-Head-Avatar checkpoint folder (random weights in GHA's layout,
  npga_core/files/gha_synthetic.py) standing in for your trained avatar;
- `session.csv`: a 30 Hz Live Link Face take (the app's CSV, 60-count timecode) of 300 frames;
- `gha_data/`: GHA tracking of the same 300 frames (`params/NNNN/params.npz`), whose expression codes are a linear
  function of the take's weights plus tracking noise, standing in for your tracker's output;
- `other_take.csv`: another take (what you then drive the avatar with).
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np


def main(argv: list[str]) -> int:
    if len(argv) != 1:
        print(__doc__.strip().splitlines()[2].strip(), file=sys.stderr)
        return 2
    from npga_core.files.arkit_takes import Take, write_livelink_csv
    from npga_core.files.blendshape_names import ARKIT_52
    from npga_core.files.gha_synthetic import write_gha_folder

    out = Path(argv[0])
    out.mkdir(parents=True, exist_ok=True)
    rng = np.random.default_rng(0)
    exp_dim = 16
    write_gha_folder(out / "gha_ckpt", n=3000, seed=1, exp_dim=exp_dim)
    a, b = 0.6 * rng.standard_normal((exp_dim, 52)), 0.2 * rng.standard_normal(exp_dim)
    for name, frames in (("session", 300), ("other_take", 150)):
        w = rng.uniform(0, 1, (frames, 52)) * (rng.uniform(0, 1, (frames, 52)) < 0.4)
        w[:, ARKIT_52.index("tongueOut")] = 0.0  # never moved, as in most real takes
        write_livelink_csv(out / f"{name}.csv", Take(w.astype(np.float32), ARKIT_52, np.arange(frames) / 30.0, 30.0),
                           start=50_000.0)
        if name == "session":
            exp = w @ a.T + b + 0.01 * rng.standard_normal((frames, exp_dim))
            for t, e in enumerate(exp):
                d = out / "gha_data" / "params" / f"{t:04d}"
                d.mkdir(parents=True, exist_ok=True)
                np.savez(d / "params.npz", exp_coeff=e[None].astype(np.float32),
                         pose=np.zeros((1, 6), np.float32), scale=np.ones(1, np.float32))
    print(f"wrote gha_ckpt/, gha_data/, session.csv and other_take.csv to {out}")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
