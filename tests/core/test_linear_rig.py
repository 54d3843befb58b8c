"""`LinearRig` in the posing path: the definition (dense numpy), `Avatar.pose`, `FastPoser`, the worker, `.npga`
version 4, sensitivity, and `--expr` names; alone and beside networks."""

from __future__ import annotations

import numpy as np
import pytest

from npga_core.errors import AvatarFileError
from npga_core.files.checkpoint import read_avatar, save_avatar
from npga_core.model.avatar import Avatar
from npga_core.model.blendshapes import BlendshapeBasis
from npga_core.model.dynamics import Dynamics
from npga_core.model.expression import ExpressionSpace
from npga_core.model.linear_rig import LinearRig
from npga_core.model.synthetic import make_synthetic_avatar
from npga_core.posing.fastpose import FastPoser, posed_buffers
from tests.support.npga_files import split_npga, write_npga

CHANNELS = ("jawOpen", "eyeBlinkLeft", "mouthSmileLeft")


def _rig(n: int, seed: int = 0, transform: np.ndarray | None = None) -> LinearRig:
    rng = np.random.default_rng(seed)
    support = np.sort(rng.choice(n, n // 3, replace=False))
    deltas = rng.normal(0, 0.01, (len(CHANNELS), len(support), 3)).astype(np.float32)
    return LinearRig(CHANNELS, support, deltas, n, scale=np.array([1.2, 1.0, 0.2]), bias=np.array([0.0, 0.1, 0.0]),
                     transform=np.eye(4) if transform is None else transform)


def _dense(rig: LinearRig, means: np.ndarray, w: np.ndarray) -> np.ndarray:
    """The definition: mu' = M (mu + sum_k (s_k w_k + b_k) delta_k), written from FORMAT.md section 17."""
    v = rig.scale.astype(np.float64) * w + rig.bias
    d = np.zeros_like(means, dtype=np.float64)
    d[rig.support] = np.einsum("k,kjc->jc", v, rig.deltas.astype(np.float64))
    x = means.astype(np.float64) + d
    return x @ rig.transform[:3, :3].T + rig.transform[:3, 3]


def _rig_only(n: int = 400, transform: np.ndarray | None = None) -> Avatar:
    cloud = make_synthetic_avatar(n, seed=5).cloud
    rig = _rig(n, transform=transform)
    k = rig.n_channels
    return Avatar(cloud, Dynamics(networks={}, rig=rig),
                  expression=ExpressionSpace(np.zeros(k), np.eye(k), np.ones(k), {"jaw": np.array([1.0, 0, 0])}),
                  blendshapes=BlendshapeBasis(CHANNELS, np.eye(k), np.zeros(k)))


def _turn() -> np.ndarray:
    m = np.eye(4)
    c, s = np.cos(0.3), np.sin(0.3)
    m[:3, :3] = [[c, 0, s], [0, 1, 0], [-s, 0, c]]
    m[:3, 3] = [0.01, -0.02, 0.03]
    return m


@pytest.mark.parametrize("transform", [None, "turned"])
def test_rig_alone_poses_as_defined_on_every_path(transform):
    a = _rig_only(transform=None if transform is None else _turn())
    rig = a.rig
    assert rig is not None and a.code_dim == 3 and a.slider_channels == CHANNELS
    w = np.array([0.7, -0.4, 1.6], np.float32)  # outside 0..1: not clamped
    ref = _dense(rig, a.cloud.means, w)
    posed = a.pose(w)
    np.testing.assert_allclose(posed.means, ref, atol=1e-6)
    np.testing.assert_allclose(a.pose(w, reference=True).means, ref, atol=1e-6)
    np.testing.assert_array_equal(posed.scales, a.pose(np.zeros(3)).scales)  # covariances static (LAM)
    np.testing.assert_array_equal(posed.quats, a.pose(np.zeros(3)).quats)
    dest = posed_buffers(len(a), 1, 0) if a.cloud.sh.shape[1] == 1 else posed_buffers(len(a), a.cloud.sh.shape[1], 0)
    poser = FastPoser(a, threads=2)
    assert poser.pose_into(w, dest)
    np.testing.assert_allclose(dest["means"], ref, atol=1e-5)
    sub = poser.subset(np.array([3, 1, 7, 399]))  # rows in any order, through the subset path
    off = poser.offsets(w, rows=sub)
    c, _ = poser.layout.blocks["position"]
    d = rig.dense_deltas()[:, [3, 1, 7, 399]]
    np.testing.assert_allclose(off[:, c : c + 3].numpy(), np.einsum("k,kjc->jc", rig.scale * w + rig.bias, d),
                               atol=1e-7)


def test_rig_beside_networks_adds_to_their_offsets():
    base = make_synthetic_avatar(300, code_dim=6, hidden=16, depth=3, n_components=4, seed=2)
    assert base.dynamics is not None
    rig = _rig(300)
    both = Avatar(base.cloud, Dynamics(networks=base.dynamics.networks(), rules=base.dynamics.rules, rig=rig))
    assert both.code_dim == base.code_dim + 3
    z = np.random.default_rng(3).normal(size=base.code_dim).astype(np.float32)
    w = np.array([0.5, 1.0, 0.0], np.float32)
    frame = np.concatenate([z, w])
    expected = _dense(rig, base.pose(z).means, w)
    np.testing.assert_allclose(both.pose(frame).means, expected, atol=1e-5)
    np.testing.assert_allclose(both.pose(frame, reference=True).means, expected, atol=1e-5)
    dest = posed_buffers(300, both.cloud.sh.shape[1], both.cloud.latent_dim)
    FastPoser(both, threads=2).pose_into(frame, dest)
    np.testing.assert_allclose(dest["means"], expected, atol=1e-5)
    assert set(both.offsets(frame).by_network) == {*base.dynamics.networks(), "rig"}


def test_version_4_round_trip_and_refusals(tmp_path):
    a = _rig_only(transform=_turn())
    path = tmp_path / "rig.npga"
    save_avatar(a, path)
    header, data = split_npga(path)
    assert header["format_version"] == 4 and header["dynamics"] is None and header["rig"]["channels"] == list(CHANNELS)
    back = read_avatar(path)
    w = np.array([0.2, 0.9, -0.3], np.float32)
    np.testing.assert_allclose(back.pose(w).means, a.pose(w).means, atol=1e-6)
    assert back.slider_channels == CHANNELS and back.blendshapes is not None

    def refused(change, expect: str) -> None:
        h = split_npga(path)[0]
        change(h)
        bad = write_npga(tmp_path / "bad.npga", h, data)
        with pytest.raises(AvatarFileError) as e:
            read_avatar(bad)
        assert expect in str(e.value) and "\n" not in str(e.value)

    refused(lambda h: h["rig"].update(carrier="triangle"), "needs format version 5")
    refused(lambda h: h["rig"].update(channels=["a", "a", "b"]), "distinct")
    refused(lambda h: h["rig"].update(support=10**6), "rig.support")
    refused(lambda h: h.update(format_version=3), "unexpected tensor")  # a rig in a version-3 file means nothing
    # a support row out of range, written into the data
    h = split_npga(path)[0]
    off = h["tensors"]["rig.support"]["offset"]
    raw = bytearray(data)
    raw[off : off + 4] = np.int32(10**6).tobytes()
    with pytest.raises(AvatarFileError, match="support"):
        read_avatar(write_npga(tmp_path / "bad2.npga", h, bytes(raw)))


@pytest.mark.slow
def test_worker_poses_a_rig_as_the_avatar_does(tmp_path):
    from npga_core.posing.engine import PoseEngine

    a = _rig_only()
    path = tmp_path / "rig.npga"
    save_avatar(a, path)
    with PoseEngine(str(path), len(a), a.cloud.sh.shape[1], 0, threads=1) as eng:
        w = np.array([1.0, 0.5, 0.25], np.float32)
        eng.request(w)
        r = eng.wait(timeout=120)
        assert r is not None
        np.testing.assert_allclose(r.posed.means, a.pose(w).means, atol=1e-5)
        assert "rig" in r.timings
        r.release()


def test_sensitivity_of_a_channel_is_its_scaled_delta():
    from npga_core.inspection.sensitivity import expression_direction, position_jvp

    a = _rig_only(transform=_turn())
    rig = a.rig
    assert rig is not None
    v = expression_direction(a, 0)
    jvp = position_jvp(a, np.zeros(3), v)
    want = rig.scale[0] * rig.dense_deltas()[0].astype(np.float64) @ rig.transform[:3, :3].T
    np.testing.assert_allclose(jvp, want, atol=1e-7)


def test_expr_names_and_weights():
    from npga_view.cli.expr_arg import ExprError, named_code

    a = _rig_only()
    np.testing.assert_array_equal(named_code("jaw", a), [1.0, 0.0, 0.0])
    np.testing.assert_allclose(named_code("JawOpen=0.5,eyeBlinkLeft=1", a), [0.5, 1.0, 0.0])  # Live Link spelling
    assert named_code("codes.npy", a) is None
    for bad, why in (("grin", "named expression"), ("jawOpen=nan", "finite"), ("tongueOut=1", "in common"),
                     ("jawOpen=1,tongueOut=1", "no shape")):
        with pytest.raises(ExprError, match=why):
            named_code(bad, a)
