"""Exact dynamics in bfloat16 (`--precision`): chosen only where the CPU multiplies it natively and the fidelity
check passes; its images match float32's (>= 45 dB over frames of a sequence, the demo and a 100k avatar); without
AMX / AVX-512 BF16 the float32 path is chosen and its output is unchanged."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from npga_core.camera.cameras import frame_points
from npga_core.files.loading import DEMO_AVATAR, DEMO_DIR, load_avatar, load_sequence
from npga_core.model.gaussians import PosedGaussians
from npga_core.model.synthetic import make_synthetic_avatar
from npga_core.posing import fastpose, precision
from npga_core.posing.fastpose import FastPoser, onednn_available, posed_buffers
from tests.support.ply_reader import read_vertices

needs_bf16 = pytest.mark.skipif(not (precision.bf16_native() and onednn_available()),
                                reason="this CPU has no native bfloat16 (AMX / AVX-512 BF16) or torch no oneDNN")


def _psnr(a: np.ndarray, b: np.ndarray) -> float:
    mse = float(np.mean((a.astype(np.float64) - b.astype(np.float64)) ** 2))
    return float("inf") if mse == 0 else 10 * np.log10(1.0 / mse)


def _posed(poser: FastPoser, z: np.ndarray) -> PosedGaussians:
    a = poser.avatar
    dest = posed_buffers(len(a), a.cloud.sh.shape[1], a.cloud.latent_dim)
    assert poser.pose_into(z, dest)
    return PosedGaussians(**dest)


def test_precision_names_and_flags():
    assert precision.check_precision(None) == "auto"
    assert precision.check_precision(" BF16 ") == "bf16"
    with pytest.raises(ValueError, match="--precision fp16"):
        precision.check_precision("fp16")
    assert set(precision.cpu_flags()) <= set(precision.REPORTED_FLAGS)
    assert "bf16" in precision.describe()


def test_without_native_bf16_auto_takes_the_unchanged_fp32_path(monkeypatch):
    a = make_synthetic_avatar(1500, latent_dim=2, seed=11)
    z = a.expression.sample(np.random.default_rng(3))
    before = FastPoser(a, chunk=256, threads=2)  # the default: float32, as before the precision option
    monkeypatch.setattr(fastpose, "bf16_native", lambda: False)
    auto = FastPoser(a, chunk=256, threads=2, precision="auto")
    assert (auto.precision, before.precision) == ("fp32", "fp32")
    assert auto.first_layer == before.first_layer and auto.rows.low is None
    assert torch.equal(auto.offsets(z), before.offsets(z))  # bit-identical
    got, ref = _posed(auto, z), _posed(before, z)
    for name in ("means", "quats", "scales", "opacities", "sh", "latent"):
        np.testing.assert_array_equal(getattr(got, name), getattr(ref, name), err_msg=name)


@pytest.mark.slow
@needs_bf16
def test_bf16_offsets_close_to_fp32_and_auto_falls_back_past_the_tolerance(monkeypatch):
    a = make_synthetic_avatar(3000, latent_dim=2, seed=12)
    z = a.expression.sample(np.random.default_rng(4))
    low, exact = FastPoser(a, chunk=512, threads=2, precision="bf16"), FastPoser(a, chunk=512, precision="fp32")
    assert low.precision == "bf16" and low.first_layer == "bf16 inputs"
    ref = exact.offsets(z)
    err = (low.offsets(z) - ref).square().mean().sqrt() / ref.square().mean().sqrt()
    assert 0 < float(err) < 0.02  # differs (it is bfloat16) but little
    assert 0 < low.fidelity() < FastPoser.BF16_TOLERANCE
    assert FastPoser(a, chunk=512, precision="auto").precision == "bf16"
    monkeypatch.setattr(FastPoser, "BF16_TOLERANCE", 1e-6)
    strict = FastPoser(a, chunk=512, precision="auto")
    assert strict.precision == "fp32" and strict.rows.low is None and strict.rows.first is not None
    assert torch.equal(strict.offsets(z), ref)


def test_bf16_needs_onednn():
    a = make_synthetic_avatar(200, seed=13)
    with pytest.raises(ValueError, match="--precision bf16"):
        FastPoser(a, kernel="aten", precision="bf16")


def _sequence_psnr(ctx, avatar, codes: np.ndarray, width: int, height: int) -> list[float]:
    from npga_view.rendering.renderer import SplatRenderer

    exact, low = FastPoser(avatar, threads=2, precision="fp32"), FastPoser(avatar, threads=2, precision="bf16")
    cam = frame_points(avatar.cloud.means, width, height)
    r = SplatRenderer(ctx, cam.width, cam.height)
    out = []
    try:
        for z in codes:
            images = []
            for poser in (exact, low):
                r.set_gaussians(_posed(poser, z))
                images.append(r.render(cam, background=(1.0, 1.0, 1.0)))
            assert not np.array_equal(images[0], images[1])  # the bfloat16 pose really ran
            out.append(_psnr(images[0], images[1]))
    finally:
        r.release()
    return out


@pytest.mark.slow
@needs_bf16
def test_bf16_demo_images_match_fp32_over_a_sequence(ctx):
    if not DEMO_AVATAR.is_file():
        pytest.skip(f"demo avatar not built ({DEMO_AVATAR})")
    avatar = load_avatar("demo")
    seq = load_sequence(DEMO_DIR / "sequences" / "talking.npzseq")
    codes = seq.codes[np.linspace(0, len(seq) - 1, 4).astype(int)]
    psnrs = _sequence_psnr(ctx, avatar, codes, 275, 401)
    assert min(psnrs) >= 45.0, psnrs


@pytest.mark.slow
@needs_bf16
def test_bf16_100k_images_match_fp32_over_a_walk(ctx):
    avatar = make_synthetic_avatar(100_000, seed=14)
    rng = np.random.default_rng(5)
    sliders = np.cumsum(rng.standard_normal((3, avatar.expression.n_components)) * 0.7, axis=0)
    codes = np.stack([avatar.expression.from_sliders(s.astype(np.float32)) for s in sliders])
    psnrs = _sequence_psnr(ctx, avatar, codes, 275, 401)
    assert min(psnrs) >= 45.0, psnrs


def test_cli_precision_flag(tmp_path, capsys, small_npga):
    from npga_view.cli.main import main

    out = tmp_path / "a.ply"
    assert main(["export", str(small_npga), "--out", str(out), "--precision", "fp16"]) == 2
    assert "--precision fp16: expected fp32, bf16 or auto" in capsys.readouterr().err
    assert not out.exists()
    assert main(["render", str(small_npga), "--out", str(tmp_path / "a.png"), "--precision", "half"]) == 2
    assert "--precision half" in capsys.readouterr().err
    assert main(["view", str(small_npga), "--precision", "fp64"]) == 2  # before any window opens
    assert "--precision fp64" in capsys.readouterr().err
    assert main(["export", str(small_npga), "--out", str(out)]) == 0  # default fp32: `Avatar.pose`, unchanged
    posed = load_avatar(str(small_npga)).pose()
    np.testing.assert_array_equal(np.column_stack([read_vertices(out)[c] for c in "xyz"]), posed.means)
    if precision.bf16_native() and onednn_available():
        assert main(["export", str(small_npga), "--out", str(out), "--precision", "bf16"]) == 0
        got = np.column_stack([read_vertices(out)[c] for c in "xyz"])
        assert not np.array_equal(got, posed.means)
        np.testing.assert_allclose(got, posed.means, atol=1e-3)


def test_peer_bench_skips_without_a_checkout(tmp_path, capsys):
    from npga_view.benchmarks.bench_peer import run

    assert run(tmp_path / "nothing", 64, 48, 2, 1, None) is None
    assert "skipped: no GaussianSplattingViewer checkout" in capsys.readouterr().out


@pytest.mark.parametrize("asked", ["fp32", "auto"])
def test_pose_worker_reports_and_uses_its_precision(small_npga, asked):
    from npga_core.posing.engine import EngineOptions, PoseEngine

    a = load_avatar(str(small_npga))
    expected = "bf16" if asked == "auto" and precision.bf16_native() and onednn_available() else "fp32"
    z = a.expression.sample(np.random.default_rng(6))
    with PoseEngine(str(small_npga), len(a), a.cloud.sh.shape[1], a.cloud.latent_dim, threads=1,
                    options=EngineOptions(precision=asked, preview=False)) as eng:
        eng.request(z, mode="exact")
        r = eng.wait(timeout=120)
        assert r is not None and eng.status.get("precision") == expected
        got, ref = r.posed.means, a.pose(z).means
        if expected == "fp32":
            np.testing.assert_allclose(got, ref, rtol=1e-5, atol=1e-7)
        else:
            assert not np.allclose(got, ref, rtol=1e-5, atol=1e-7)
            np.testing.assert_allclose(got, ref, atol=1e-3)
