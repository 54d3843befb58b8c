"""Preview posing: bounded error on a small avatar, exact probes, model cache keyed by content, engine flags."""

from __future__ import annotations

import time

import numpy as np
import pytest
import torch

from npga_core.files.checkpoint import read_avatar
from npga_core.model.synthetic import make_synthetic_avatar
from npga_core.posing.engine import PoseEngine
from npga_core.posing.fastpose import FastPoser, posed_buffers
from npga_core.posing.preview import Previewer, PreviewModel, preview_cache_path


@pytest.fixture(scope="module")
def setup():
    a = make_synthetic_avatar(3000, seed=11)
    poser = FastPoser(a, chunk=512)
    geo = PreviewModel.geometric(a.cloud.means, 400, 8)
    fit = PreviewModel.fit(poser, PreviewModel.sample_codes(a, 6, seed=1), a.neutral_code(), 400, 8)
    return a, poser, geo, fit


def _moves(a, count: int = 4):
    """(z0, z1) pairs: a random expression and the same with one leading slider moved by 1 std."""
    ex, rng = a.expression, np.random.default_rng(0)
    for k in range(count):
        s0 = (0.7 * rng.standard_normal(ex.n_components)).astype(np.float32)
        s1 = s0.copy()
        s1[k] += 1.0
        yield ex.from_sliders(s0), ex.from_sliders(s1)


@pytest.mark.parametrize("precision", ["fp32", "bf16"])
def test_preview_error_is_bounded_and_fitting_helps(setup, precision):
    a, poser, geo, fit = setup
    errors = {}
    for name, model in (("geometric", geo), ("fitted", fit)):
        pv = Previewer(poser, model, precision=precision)
        rel = []
        for z0, z1 in _moves(a):
            o0, o1 = poser.offsets(z0), poser.offsets(z1)
            pv.set_base(z0, o0)
            approx = pv.offsets(z1)
            change = (o1 - o0).norm(dim=1).mean()
            rel.append(float((approx - o1).norm(dim=1).mean() / change))
            position = approx[:, :3] + approx[:, 3:6] - (o1[:, :3] + o1[:, 3:6])  # F + G position offsets
            moved = (o1[:, :3] + o1[:, 3:6] - o0[:, :3] - o0[:, 3:6]).norm(dim=1)
            assert float(position.norm(dim=1).mean()) < 0.6 * float(moved.mean())
        errors[name] = float(np.mean(rel))
        assert errors[name] < 0.6, errors
    assert errors["fitted"] < errors["geometric"], errors


def test_probes_are_exact_and_weights_normalised(setup):
    a, poser, geo, fit = setup
    np.testing.assert_allclose(geo.weights.sum(1), 1.0, atol=1e-5)
    assert fit.fitted_codes == 6 and fit.sensitivity is not None and fit.sensitivity.shape == (len(a),)
    pv = Previewer(poser, fit, precision="fp32")
    z0, z1 = next(_moves(a))
    pv.set_base(z0, poser.offsets(z0))
    exact = poser.offsets(z1)
    torch.testing.assert_close(pv.offsets(z1)[fit.probes], exact[fit.probes], rtol=1e-5, atol=1e-7)


def test_pose_into_applies_the_preview_offsets(setup):
    a, poser, _, fit = setup
    pv = Previewer(poser, fit)
    z0, z1 = next(_moves(a))
    pv.set_base(z0, poser.offsets(z0))
    dest, again = (posed_buffers(len(a), a.cloud.sh.shape[1], 0) for _ in range(2))
    pv.pose_into(z1, dest)
    poser.apply_into(pv.offsets(z1), again)
    for name in dest:
        np.testing.assert_allclose(dest[name], again[name], rtol=1e-5, atol=1e-6)


def test_model_cache_is_keyed_by_content(setup, tmp_path):
    a, _, _, fit = setup
    fit.key = a.content_key()
    path = tmp_path / "m.npz"
    fit.save(path)
    back = PreviewModel.load(path, a.content_key(), len(a))
    assert back is not None and back.fitted_codes == fit.fitted_codes
    np.testing.assert_array_equal(back.weights, fit.weights)
    np.testing.assert_array_equal(back.neighbours, fit.neighbours)
    assert PreviewModel.load(path, "another-avatar", len(a)) is None
    assert PreviewModel.load(path, a.content_key(), len(a) + 1) is None
    assert PreviewModel.load(tmp_path / "missing.npz", a.content_key(), len(a)) is None


@pytest.mark.slow
def test_engine_previews_then_refines_to_the_exact_pose(small_npga, tmp_path):
    a = read_avatar(small_npga)
    opts = {"instant_ms": 0.0, "probes": 64, "fit_codes": 2, "cache_dir": str(tmp_path)}
    with PoseEngine(str(small_npga), len(a), a.cloud.sh.shape[1], a.cloud.latent_dim, threads=1, **opts) as eng:
        eng.request(a.neutral_code(), mode="exact")
        first = eng.wait()
        assert first is not None and not first.preview
        first.release()
        z = a.expression.sample(np.random.default_rng(5))
        rid = eng.request(z, mode="preview")
        r = eng.wait()
        assert r is not None and r.request_id == rid and r.preview and eng.refining
        r.release()
        r = eng.wait(exact=True)
        assert r is not None and r.request_id == rid and not r.preview and not eng.refining
        ref = a.pose(z)
        for name in ("means", "quats", "scales", "opacities", "sh", "latent"):
            np.testing.assert_allclose(getattr(r.posed, name), getattr(ref, name), rtol=1e-4, atol=2e-6)
        r.release()
        end = time.monotonic() + 60
        while eng.status.get("preview_model") != "fitted" and time.monotonic() < end:
            eng.poll()
            time.sleep(0.02)
        assert eng.status.get("preview_model") == "fitted"
    cached = preview_cache_path(small_npga, a.content_key(), 64, 8, 2, tmp_path)
    assert cached.is_file()
    with PoseEngine(str(small_npga), len(a), a.cloud.sh.shape[1], a.cloud.latent_dim, threads=1, **opts) as eng:
        eng.request(a.neutral_code(), mode="exact")
        eng.wait().release()
        end = time.monotonic() + 30
        while eng.status.get("preview_model") in (None, "pending") and time.monotonic() < end:
            eng.poll()
            time.sleep(0.02)
        assert eng.status.get("preview_model") == "cached"


@pytest.mark.slow
def test_refinement_waits_for_a_pause_without_newer_requests(small_npga, tmp_path):
    """The exact refinement of a preview starts only after `refine_delay_ms` without a newer request (the window's
    image of the preview gets the cores first): previews of a drag in between are answered, each refinement
    dropped for the next, and only the last one's exact pose comes."""
    a = read_avatar(small_npga)
    opts = {"instant_ms": 0.0, "probes": 64, "fit_codes": 0, "cache_dir": str(tmp_path), "refine_delay_ms": 1500.0}
    with PoseEngine(str(small_npga), len(a), a.cloud.sh.shape[1], a.cloud.latent_dim, threads=1, **opts) as eng:
        eng.request(a.neutral_code(), mode="exact")
        eng.wait().release()
        rng = np.random.default_rng(9)
        ids = []
        for _ in range(3):  # a drag: a new code well within the pause each time
            ids.append(eng.request(a.expression.sample(rng), mode="preview"))
            r = eng.wait()
            assert r is not None and r.request_id == ids[-1] and r.preview
            r.release()
            t0 = time.monotonic()
            while time.monotonic() - t0 < 0.2:  # no exact pose during the pause
                r = eng.poll()
                assert r is None or r.preview, "an exact pose came before the pause was over"
                if r is not None:
                    r.release()
                time.sleep(0.01)
        r = eng.wait(exact=True)
        assert r is not None and r.request_id == ids[-1] and not r.preview
        r.release()
