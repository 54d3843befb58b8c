"""Baked sequences: quantisation error, budget, interpolation, and the cache reused only when nothing changed."""

from __future__ import annotations

import time

import numpy as np
import pytest
import torch

from npga_core.files.checkpoint import read_avatar, save_avatar
from npga_core.posing.bake import BakeStore, bake_key, cache_path, plan_stride
from npga_core.posing.engine import PoseEngine


@pytest.mark.parametrize("seed", range(5))
def test_quantisation_error_is_half_a_step(seed):
    gen = torch.Generator().manual_seed(seed)
    rows = torch.randn(500, 7, generator=gen) * torch.tensor([1e-3, 1e-2, 0.1, 1.0, 5.0, 1e-5, 0.0])
    for bits in (8, 16):
        store = BakeStore.create("k", 3, 500, 7, bits)
        store.put(1, rows)
        out = torch.empty(500, 7)
        store.offsets_into(store.stored_frames[1], out)
        step = torch.from_numpy(store.step[1])
        float_error = 1e-6 * rows.abs().amax(0)  # float32 rounding of the scaling, a few ulp of the range
        assert torch.all((out - rows).abs() <= 0.5 * step + float_error)


def test_budget_sets_the_stride_and_frames_between_are_interpolated():
    per_frame = 100 * 4 + 2 * 4 * 4
    assert plan_stride(10, 100, 4, 8, 10 * per_frame) == 1
    stride = plan_stride(10, 100, 4, 8, 4 * per_frame)
    store = BakeStore.create("k", 10, 100, 4, 8, 4 * per_frame)
    assert store.stride == stride and len(store.stored_frames) <= 4 and store.stored_frames[-1] == 9
    assert store.nbytes <= 4 * per_frame
    with pytest.raises(ValueError, match="fewer than 2 frames"):
        plan_stride(10, 100, 4, 8, per_frame)
    a, b = torch.zeros(100, 4), torch.ones(100, 4)
    store.put(0, a)
    store.put(1, b)
    out = torch.empty(100, 4)
    f = stride // 2 if stride > 1 else 1
    store.offsets_into(f, out)
    assert not store.exact(f) or stride == 1
    torch.testing.assert_close(out, torch.full((100, 4), f / stride), atol=1e-6, rtol=0)
    with pytest.raises(ValueError, match="not baked"):
        store.offsets_into(9, out)


def test_cache_file_roundtrip_and_key(tmp_path):
    store = BakeStore.create("abc", 4, 50, 3, 8)
    for i in range(len(store.done)):
        store.put(i, torch.randn(50, 3) * (i + 1))
    path = tmp_path / "x.npgabake"
    store.save(path)
    back = BakeStore.open(path, "abc")
    assert back is not None and back.complete and back.frames == 4
    np.testing.assert_array_equal(np.asarray(back.data), store.data)
    assert BakeStore.open(path, "other") is None
    assert BakeStore.open(tmp_path / "missing", "abc") is None
    codes = np.zeros((4, 3), np.float32)
    assert bake_key("a", codes, 8, 1) != bake_key("b", codes, 8, 1)
    assert bake_key("a", codes, 8, 1) != bake_key("a", codes + 1, 8, 1)
    assert bake_key("a", codes, 8, 1) != bake_key("a", codes, 16, 1)


def _codes(a, frames: int, seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    return np.stack([a.expression.sample(rng) for _ in range(frames)]).astype(np.float32)


def _engine(path, a, tmp_path):
    return PoseEngine(str(path), len(a), a.cloud.sh.shape[1], a.cloud.latent_dim, threads=1, preview=False,
                      cache_dir=str(tmp_path))


@pytest.mark.slow
def test_engine_bakes_plays_and_reuses_the_cache(small_npga, tmp_path):
    a = read_avatar(small_npga)
    codes = _codes(a, 6, 0)
    with _engine(small_npga, a, tmp_path) as eng:
        eng.bake(codes)
        st = eng.wait_bake(timeout=120)
        assert st is not None and st.finished and not st.from_cache and st.error is None
        assert st.stored == 6 and st.stride == 1
        rid = eng.request_frame(3)
        r = eng.wait()
        assert r.request_id == rid and r.frame == 3 and r.baked and not r.preview
        ref = a.pose(codes[3])
        np.testing.assert_allclose(r.posed.means, ref.means, atol=2e-5)
        np.testing.assert_allclose(r.posed.opacities, ref.opacities, atol=2e-3)
        r.release()
        eng.bake(codes)  # same avatar, same codes: from the cache file
        st = eng.wait_bake(timeout=60)
        assert st.finished and st.from_cache
    with _engine(small_npga, a, tmp_path) as eng:  # a new worker finds the file too
        eng.bake(codes)
        assert eng.wait_bake(timeout=60).from_cache
        eng.bake(_codes(a, 6, 1))  # another sequence: baked again
        st = eng.wait_bake(timeout=120)
        assert st.finished and not st.from_cache
    key = bake_key(a.content_key(), codes, 8, 1024 * 2**20)
    assert cache_path(small_npga, key, tmp_path).is_file()


@pytest.mark.slow
def test_cache_follows_the_avatar_content_not_the_file(small_npga, tmp_path):
    a = read_avatar(small_npga)
    codes = _codes(a, 4, 2)
    path = tmp_path / "head.npga"

    def bake() -> bool:
        b = read_avatar(path)
        with _engine(path, b, tmp_path) as eng:
            eng.bake(codes)
            st = eng.wait_bake(timeout=120)
            assert st is not None and st.finished and st.error is None
            return st.from_cache

    save_avatar(a, path)
    assert not bake()
    save_avatar(read_avatar(small_npga), path)  # written again, same content: reused
    assert bake()
    edited = read_avatar(small_npga)
    cloud = edited.cloud.copy()
    cloud.opacity_logits[:10] += 1.0
    edited.cloud = cloud
    edited.invalidate_caches()
    assert edited.content_key() != a.content_key()
    save_avatar(edited, path)  # an edit session saved over the file: baked again
    assert not bake()


@pytest.mark.slow
def test_frame_asked_just_before_a_cancel_is_answered(small_npga, tmp_path):
    """A frame request and a cancel that reach the worker together: the frame comes from the bake, no error
    (the viewer showed "no baked sequence" when the bake was dropped during baked playback)."""
    a = read_avatar(small_npga)
    codes = _codes(a, 4, 0)
    with _engine(small_npga, a, tmp_path) as eng:
        eng.bake(codes)
        assert eng.wait_bake(timeout=120).finished
        held = []
        for f in (0, 1):  # hold both slots: the next answer waits in the worker until one is released
            eng.request_frame(f)
            held.append(eng.wait())
        eng.request_frame(2)  # the worker takes it and blocks for a slot
        time.sleep(0.5)
        rid = eng.request_frame(3)  # these two are read together, after the blocked answer
        eng.cancel_bake()
        for r in held:
            r.release()
        r = eng.wait(timeout=60)
        assert eng.last_error is None
        assert r is not None and r.request_id == rid and r.frame == 3 and r.baked
        r.release()
