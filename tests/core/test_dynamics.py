"""Dynamics: fast path vs the plain reference, the group operations, configurations."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from npga_core.model.dynamics import ATTRIBUTE_OPS, ConditionedMLP, MLPConfig, quat_multiply
from npga_core.model.synthetic import make_synthetic_avatar


@pytest.mark.parametrize("kw", [
    {},
    {"sh_degree": 1, "latent_dim": 3},
    {"feature_dim": 0, "hidden": 32, "depth": 2},
])
def test_fast_path_equals_reference(kw):
    a = make_synthetic_avatar(700, seed=5, **kw)
    z = a.expression.sample(np.random.default_rng(2))
    fast, ref = a.offsets(z, chunk=256), a.offsets_reference(z)
    torch.testing.assert_close(fast.f_position, ref.f_position, rtol=1e-4, atol=1e-6)
    for k in ref.g:
        torch.testing.assert_close(fast.g[k], ref.g[k], rtol=1e-4, atol=1e-6)


@pytest.mark.parametrize("cfg", [
    MLPConfig(5, 6, [("position", 3)], hidden=16, depth=4, activation="silu", pos_freqs=2, skips=[2]),
    MLPConfig(2, 4, [("position", 3), ("opacity", 1)], hidden=8, depth=1, activation="tanh"),
])
def test_evaluate_matches_forward_for_other_architectures(cfg):
    torch.manual_seed(0)
    net = ConditionedMLP(cfg)
    mu, f, z = torch.randn(300, 3), torch.randn(300, cfg.feature_dim), torch.randn(cfg.code_dim)
    ref = net(mu, f, z)
    got = net.evaluate(net.precompute(mu, f), z, chunk=64, gaussian_inputs=(mu, f))
    torch.testing.assert_close(got, ref, rtol=1e-4, atol=1e-5)


def test_zero_offsets_are_neutral_for_every_op():
    q = torch.nn.functional.normalize(torch.randn(10, 4), dim=-1)
    assert torch.allclose(ATTRIBUTE_OPS["rotation"].apply(q, torch.zeros(10, 4)), q, atol=1e-6)
    assert torch.allclose(ATTRIBUTE_OPS["rotation_add"].apply(q, torch.zeros(10, 4)), q, atol=1e-6)
    for name in ("position", "scale", "opacity", "sh", "latent"):
        x = torch.randn(10, 3)
        assert torch.equal(ATTRIBUTE_OPS[name].apply(x, torch.zeros(10, 3)), x)


def test_rotation_compose_applies_the_offset_rotation():
    # a 90 degree turn about z, expressed as offset d = q_z - identity
    qz = torch.tensor([[np.cos(np.pi / 4), 0, 0, np.sin(np.pi / 4)]], dtype=torch.float32)
    q = torch.tensor([[1.0, 0, 0, 0]])
    d = qz - torch.tensor([[1.0, 0, 0, 0]])
    assert torch.allclose(ATTRIBUTE_OPS["rotation"].apply(q, d), qz, atol=1e-6)
    # Hamilton product sanity: i*j = k
    i, j = torch.tensor([0.0, 1, 0, 0]), torch.tensor([0.0, 0, 1, 0])
    assert torch.equal(quat_multiply(i, j), torch.tensor([0.0, 0, 0, 1]))


def test_pose_applies_offsets_by_group_operations():
    a = make_synthetic_avatar(200, seed=1, latent_dim=2)
    z = a.expression.sample(np.random.default_rng(0))
    off = a.offsets_reference(z)
    p = a.pose(z)
    c = a.cloud
    exp_means = c.means + (off.f_position + off.g["position"]).numpy()
    np.testing.assert_allclose(p.means, exp_means, atol=1e-6)
    np.testing.assert_allclose(np.log(p.scales), c.log_scales + off.g["scale"].numpy(), atol=1e-5)
    sig = 1 / (1 + np.exp(-(c.opacity_logits + off.g["opacity"].numpy()[:, 0])))
    np.testing.assert_allclose(p.opacities, sig, atol=1e-6)
    np.testing.assert_allclose(p.sh, c.sh + off.g["sh"].numpy().reshape(c.sh.shape), atol=1e-6)
    np.testing.assert_allclose(p.latent, c.latent + off.g["latent"].numpy(), atol=1e-6)
    np.testing.assert_allclose(np.linalg.norm(p.quats, axis=1), 1.0, atol=1e-5)


def test_offsets_are_expression_dependent_and_small():
    a = make_synthetic_avatar(300, seed=2)
    rng = np.random.default_rng(3)
    p0, p1 = a.pose(), a.pose(a.expression.sample(rng))
    moved = np.linalg.norm(p1.means - p0.means, axis=1)
    assert moved.max() > 1e-4 and moved.mean() < 0.02


def test_config_validation_messages():
    with pytest.raises(ValueError, match="activation"):
        MLPConfig(1, 1, [("position", 3)], activation="swish2").validate()
    with pytest.raises(ValueError, match="unknown output block"):
        MLPConfig(1, 1, [("colour", 3)]).validate()
    with pytest.raises(ValueError, match="skip"):
        MLPConfig(1, 1, [("position", 3)], depth=3, skips=[3]).validate()


def test_wrong_code_dimension_is_refused_with_both_numbers():
    a = make_synthetic_avatar(20, seed=0)
    with pytest.raises(ValueError, match="50 dims, the avatar expects 100"):
        a.pose(np.zeros(50))
