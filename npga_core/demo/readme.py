"""The demo folder's place and its README.txt, shared by the build's two stages (build.py, refine_stage.py)."""

from __future__ import annotations

from pathlib import Path

DEFAULT_OUT = Path(__file__).resolve().parents[2] / "assets" / "demo"


def write_readme(out: Path, seed: int, quick: bool, summary: dict) -> None:
    """Write OUT/README.txt from a build summary (the base stage's, with the refine stage's under `refine`)."""
    f = summary["f_error_mm"]["held_out"]
    text = f"""npga-view demo avatar
=====================

avatar.npga            NPGA avatar: {summary['gaussians']} Gaussians (SH degree 1, 8-D features), dynamics F and G
                       (6 x 256 MLPs, 100-D expression codes), expression statistics and named expressions.
sequences/*.npzseq     Animations at 25 fps in the npga-view sequence format: {', '.join(summary['sequences'])}.
expression_map.npz     The fixed map between codes and the 53 ARKit-style blendshape weights:
                       z = M w + b, w = M^T (z - b)  (arrays M, b, names).
LICENSE.ict-facekit    Licence of the source data (MIT), which must travel with this folder.

Provenance: derived from the ICT-FaceKit light head model (USC Institute for Creative Technologies,
MIT licence, see LICENSE.ict-facekit). The Gaussians were sampled on its neutral surfaces and coloured
procedurally; F and G were distilled from its 53 expression blendshapes (plus an eyeball rotation for
gaze). Built by `python -m npga_core.demo.build --seed {seed}{' --quick' if quick else ''}` in
{summary['build_seconds']:.0f} s ({summary['machine']}). See docs/DEMO.md.

F position error on {summary['test_expressions']} held-out expressions (mm):
  all Gaussians  mean {f['all']['mean']:.3f}  p99 {f['all']['p99']:.3f}
  lips           mean {f['lips']['mean']:.3f}  p99 {f['lips']['p99']:.3f}
  eyelids        mean {f['eyelids']['mean']:.3f}  p99 {f['eyelids']['p99']:.3f}
"""
    r = summary.get("refine")
    if r:
        m, c = r["held_out"], r["config"]
        text += f"""
Refinement (`python -m npga_core.demo.build --stage refine --seed {r['seed']}`, {r['seconds']:.0f} s): per-Gaussian
latent features h ({c['latent_dim']} channels), G's offsets of h (a `latent` block read out of G's last hidden
layer) and a screen-space CNN ({len(c['cnn_kernels'])} convolutions, {c['cnn_width']} wide, residual), trained
against the ICT head itself rendered per pixel. On {m['crops']} held-out crops (expressions and views):
  raw splats vs target   PSNR {m['raw_psnr']:.2f} dB  SSIM {m['raw_ssim']:.4f}
  CNN output vs target   PSNR {m['cnn_psnr']:.2f} dB  SSIM {m['cnn_ssim']:.4f}
"""
    (out / "README.txt").write_text(text)
